//! The motion crate's tests that read files or run whole fits (the unit tests sit beside their
//! code), linked into one binary: the simulator against analytic and converged references,
//! the gradients against finite differences, the optimisers, the dataset reader, the loads, the
//! spline material and the static solve.

mod support;

mod cantilever;
mod creep;
mod dataset;
mod dataset_write;
mod fit;
mod gauss_newton;
mod gradients;
mod load_point;
mod loads;
mod quadratic_motion;
mod quadratic_statics;
mod schemes;
mod shear_thinning;
mod spline;
mod statics;
mod step_solve;
