//! The co-adaptation's errors are the fleet's [`AppError`](coadapt_fleet::app::AppError), as every
//! application's; `Context` adds what was being done. Here: the short forms this crate writes
//! them with.

pub use coadapt_fleet::app::Context;

/// `return Err(AppError::Failed(format!(...)))`.
macro_rules! bail {
    ($($arg:tt)*) => {
        return Err(coadapt_fleet::app::AppError::Failed(format!($($arg)*)))
    };
}
pub(crate) use bail;

/// `return Err(AppError::Config(format!(...)))`: a setting is wrong.
macro_rules! bail_config {
    ($($arg:tt)*) => {
        return Err(coadapt_fleet::app::AppError::Config(format!($($arg)*)))
    };
}
pub(crate) use bail_config;

/// `AppError::Failed(format!(...))`.
macro_rules! failed {
    ($($arg:tt)*) => {
        coadapt_fleet::app::AppError::Failed(format!($($arg)*))
    };
}
pub(crate) use failed;
