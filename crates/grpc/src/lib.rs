//! coadapt over gRPC (being written).
