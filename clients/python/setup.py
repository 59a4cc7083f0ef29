"""Builds coadapt-client with its gRPC stubs generated from the checkout's proto/ files.

The DesignService's modules go to ``coadapt_client/_proto/`` inside the built package (never into
the source tree), with their imports rewritten to stay inside it. The Open Inference Protocol's
messages (package ``inference``) are shipped as a descriptor set (``_proto/oip.pb``) that the
client loads into a private descriptor pool: Triton's client registers the same message names in
protobuf's default pool, and two registrations of one name refuse each other.
"""

import pathlib
import re

from setuptools import setup
from setuptools.command.build_py import build_py

HERE = pathlib.Path(__file__).resolve().parent
PROTO = HERE.parent.parent / "proto"
DESIGN = "coadapt/v1/design.proto"
OIP = "inference/grpc_predict_v2.proto"
FILES = [DESIGN, OIP]


def generate(out: pathlib.Path) -> None:
    from grpc_tools import protoc

    missing = [f for f in FILES if not (PROTO / f).is_file()]
    if missing:
        raise SystemExit(f"coadapt-client: {PROTO} lacks {missing}: build the package from a coadapt checkout "
                         "(pip install ./clients/python)")
    out.mkdir(parents=True, exist_ok=True)
    include = pathlib.Path(protoc.__file__).parent / "_proto"
    args = ["protoc", f"-I{PROTO}", f"-I{include}", f"--python_out={out}", f"--pyi_out={out}",
            f"--grpc_python_out={out}", str(PROTO / DESIGN)]
    if protoc.main(args) != 0:
        raise SystemExit(f"coadapt-client: protoc failed on {DESIGN}")
    args = ["protoc", f"-I{PROTO}", f"-I{include}", "--include_imports", f"--descriptor_set_out={out / 'oip.pb'}", str(PROTO / OIP)]
    if protoc.main(args) != 0:
        raise SystemExit(f"coadapt-client: protoc failed on {OIP}")
    for d in (out, out / "coadapt", out / "coadapt" / "v1"):
        (d / "__init__.py").touch()
    for f in out.rglob("*_pb2_grpc.py"):
        text = re.sub(r"^from coadapt\.v1 import", r"from coadapt_client._proto.coadapt.v1 import", f.read_text(), flags=re.M)
        f.write_text(text)


class BuildWithStubs(build_py):
    def run(self):
        super().run()
        generate(pathlib.Path(self.build_lib) / "coadapt_client" / "_proto")


setup(cmdclass={"build_py": BuildWithStubs})
