//! # volwarp-client
//!
//! The thin client of Zellmann 2020 (Figure 2, right): it receives compacted object-space
//! samples, builds an LBVH over them as spheres and ray traces them for the camera of *now*,
//! at display rate, however slowly frames arrive.
//!
//! | module | concept |
//! |---|---|
//! | [`connection`] | TCP connect, Hello exchange, the probe frame that gives the volume bounds |
//! | [`network`] | the network thread: receive, delay (`--latency-ms`), LBVH build, newest-camera writer |
//! | [`link`] | the link model of `--bandwidth-mbps`: a token bucket on the socket's reads and writes |
//! | [`display`] | one display frame: swap in the newest scene without waiting, draw it for the current camera |
//! | [`renderers`] | the interchangeable renderers and live switching (GPU opened lazily) |
//! | [`controls`] | orbit, pan and zoom; the home view of a volume |
//! | [`window`] | the minifb window, its input and status title |
//! | [`headless`] | the scripted orbit that writes PNG frames and `timings.csv` |
//! | [`bench`](mod@bench) | the display-rate benchmark while frames are decoded and built |
//! | [`record`] / [`replay`] | saving the received stream and playing it back offline |
//! | [`server_process`] | the real `volwarp-server` as a child process (demo, `--prerender`) |
//! | [`feed_server`] | prerendered frames served at a fixed pace, to benchmark the client alone |
//! | [`options`], [`error`], [`app`] | command line, errors, putting it together |
//!
//! The wire format, record format and the client's use of them are documented in `docs/`.
#![deny(missing_docs)]
#![forbid(unsafe_code)]

pub mod app;
pub mod bench;
pub mod connection;
pub mod controls;
pub mod display;
pub mod error;
pub mod feed_server;
pub mod headless;
pub mod link;
pub mod network;
pub mod options;
pub mod record;
pub mod renderers;
pub mod replay;
pub mod server_process;
pub mod visual;
pub mod window;

pub use app::run;
pub use error::ClientError;
pub use options::Options;
