//! # volwarp-tests
//!
//! Cross-crate integration tests (in `tests/`): the real `volwarp-server` and the
//! `volwarp-client` library together over loopback TCP. Tests of one crate live with that
//! crate; the evaluation's own tests are in `eval/`. This library is empty on purpose.
#![deny(missing_docs)]
#![forbid(unsafe_code)]
