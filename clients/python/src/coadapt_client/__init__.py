"""A typed client for coadapt's design service (``coadapt serve RUN_DIR``, or a learner serving
during its run with ``--serve ADDR``): what the learned critic thinks of robot designs.

    from coadapt_client import DesignClient

    with DesignClient("127.0.0.1:50061") as c:               # TLS: tls_ca="ca.pem"
        info = c.info()                                       # robot, named dimensions, box
        scores = c.score(np.array([[1, 1, 1, 1, 1, 1]]))      # Eq. 5.6: value, spread, disagreement
        best = c.optimize(particles=100, iterations=50, on_progress=print)
        rows = c.history()                                    # designs.csv, every page
        for row in c.watch(): ...                             # each design as it changes

Tokens are read from ``COADAPT_TOKEN`` or a file (``token_file=``), never taken as an argument,
and sent only over TLS or to a loopback address. Every call has a deadline. Designs go in and
scores come out as numpy arrays; a malformed design is refused before anything is sent, with
an error naming the row and the column, and the server's refusals (``INVALID_ARGUMENT``) come
back as :class:`CoadaptError` naming the field.
"""

from ._client import DesignClient
from ._errors import CoadaptError
from ._types import Dimension, Info, Landscape, Optimized, Progress, Record, Scores

__all__ = ["DesignClient", "CoadaptError", "Dimension", "Info", "Landscape", "Optimized", "Progress", "Record", "Scores"]
__version__ = "0.1.0"
