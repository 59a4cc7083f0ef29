//! coadapt over iceoryx2 shared memory (being written).
