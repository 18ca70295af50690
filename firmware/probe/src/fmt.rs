//! Logging shim: forwards to `defmt` with the `defmt` feature (board binary only); otherwise
//! the arguments are only borrowed (no unused-variable warnings) and nothing is emitted.

#[cfg(feature = "defmt")]
macro_rules! log_info {
    ($($t:tt)*) => { defmt::info!($($t)*) };
}
#[cfg(not(feature = "defmt"))]
macro_rules! log_info {
    ($fmt:literal $(, $arg:expr)* $(,)?) => {{ $( let _ = &$arg; )* }};
}
#[cfg(feature = "defmt")]
macro_rules! log_warn {
    ($($t:tt)*) => { defmt::warn!($($t)*) };
}
#[cfg(not(feature = "defmt"))]
macro_rules! log_warn {
    ($fmt:literal $(, $arg:expr)* $(,)?) => {{ $( let _ = &$arg; )* }};
}

pub(crate) use log_info;
pub(crate) use log_warn;
