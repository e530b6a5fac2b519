//! # volwarp-server
//!
//! The server of Zellmann 2020, Figure 2: it loads a volume and a transfer function, ray
//! marches each pixel of the camera a client asks for, picks a representative depth per pixel
//! with one of the ZAL12 heuristics, turns every non-empty pixel into an object-space sample
//! (`p = o + d·t`, radius the pixel's footprint at that depth or half a voxel diagonal), quantizes and compacts the samples and sends
//! them over TCP with the camera they belong to.
//!
//! | module | concept |
//! |---|---|
//! | [`volume`] | scalar volumes, world-space placement (LPS), Marschner–Lobb; loaders of raw, NRRD, NIfTI, TIFF stacks, VTK image data and DICOM series |
//! | [`nrrd`] | NRRD headers and data (raw, gzip; attached and detached) |
//! | [`transfer_function`] | 1-D RGBA lookup tables, presets, ParaView JSON and text files |
//! | [`dataset`] | a volume with its transfer function; the bundled default |
//! | [`encoding`] | the wire encoding of a frame: 12-byte or compact, negotiated per client |
//! | [`empty_space`] | the min/max brick grid for empty-space skipping |
//! | [`march_settings`] | what both marching kernels march with: options, a ray's samples in the box |
//! | [`marcher`] | the CPU ray marcher: frames for clients and ground-truth images |
//! | [`packet_march`] | the marcher's fast kernel: 8, 16 or 32 rays at once in SIMD lanes ([`LaneKind`]) |
//! | [`radius`] | the sphere radius models: pixel footprint or half a voxel diagonal |
//! | [`compaction`] | the parallel compaction of a frame's samples |
//! | [`render_queue`] | one marcher pool shared by all clients; identical requests rendered once |
//! | [`server`] | the TCP server: handshake, latest-wins requests, limits |
//! | [`synth`] | synthetic volumes of any size, streamed to raw files (`volwarp-server synth`) |
//! | [`testdata`] | the shared datasets beside the project, for tests and benchmarks |
//!
//! ```no_run
//! use volwarp_server::{dataset::Dataset, server::{Server, ServerConfig}};
//! let server = Server::bind(ServerConfig::default(), Dataset::default_bundled()).unwrap();
//! println!("listening on {}", server.local_addr());
//! let handle = server.spawn();
//! // ... connect clients ...
//! handle.shutdown();
//! ```
#![deny(missing_docs)]

pub mod compaction;
pub mod dataset;
pub mod distributed;
pub mod empty_space;
pub mod encoding;
mod lanes;
pub mod march_settings;
pub mod marcher;
pub mod packet_march;
pub use volume::nrrd;
pub mod radius;
pub mod render_queue;
pub mod server;
pub mod synth;
pub mod testdata;
pub mod transfer_function;
pub mod visual;
pub mod volume;

pub use dataset::Dataset;
pub use lanes::{lane_kind, limit_lanes, limit_lanes_from_env, LaneKind};
pub use marcher::{default_camera, FrameStats, LayerBuffer, MarchKernel, MarchOptions, Marcher, PixelBuffer};
pub use radius::RadiusModel;
pub use server::{Server, ServerConfig, ServerHandle, TlsIdentity};
pub use transfer_function::TransferFunction;
pub use volume::{load_volume, LoadOptions, Volume, VolumeError};
