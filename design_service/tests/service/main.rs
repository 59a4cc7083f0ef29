//! The DesignService and the Open Inference Protocol over a real server on port 0: values
//! against a plain forward pass of the networks, ModelInfer equal to Score, every malformed
//! request answered INVALID_ARGUMENT naming its field, History paged on whole designs, health
//! and reflection, Optimize and Landscape, Watch over a live run, and a server's stop.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

mod support;

mod history;
mod live;
mod optimize;
mod score;
