//! `canopy bench`: flights (keyframed cameras, suns and knobs), the temporal measures
//! (flicker against the truth's own flicker, the worst pop), the Pareto front of cost against
//! error, the key and store of the cached ground-truth frames, the PNG charts (the pure-CPU
//! half), and the runner that renders the truth and every configuration along a flight, its
//! report files and the command itself.

pub mod chart;
pub mod command;
pub mod flight;
pub mod pareto;
pub mod report;
pub mod run;
pub mod temporal;
pub mod truth_key;
pub mod tune;

pub use chart::{ChartPoint, DEFAULT_CHART_SIZE, FlightSeries, flight_chart, speed_accuracy_chart};
pub use flight::{Flight, FlightContext, FlightFrame, FlightKey, Knobs, PathShape};
pub use pareto::pareto_front;
pub use temporal::{Flicker, Pop, flicker, flicker_excess};
pub use truth_key::{TRUTH_REVISION, TruthKey, TruthLookup, TruthRequest, scene_content};
