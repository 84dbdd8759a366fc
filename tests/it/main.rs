//! octolod's integration tests, one binary: a module per subject, all on
//! the harness in [`common`] (one command helper, one fixture set).
//!
//! `cargo test --locked` runs them; the slowest cases (1 M-triangle
//! inputs) are `#[ignore]`d, each covered by a smaller case that runs by
//! default, and run with `tools/slow-tests.sh` (`cargo test --locked --
//! --ignored`). A test needing a GPU (Mesa lavapipe in CI) fails without
//! one unless OCTOLOD_SKIP_GPU_TESTS=1; a browser test fails without
//! `tools/ci-deps.sh`'s Chromium and npm packages unless
//! OCTOLOD_SKIP_WEB_TESTS=1, as does a test on real files from npm
//! packages without node and npm (`real_inputs`, through
//! `tools/real-inputs.sh`). Without the `view` feature the modules and
//! tests that render are left out.
//!
//! All modules share this process: each test works in its own temporary
//! directory, sets no environment variable of its own, and runs a part
//! that needs a process of its own (another environment, a fresh address
//! space) as a child: [`common::this_test_again`].

mod common;

mod bad_input;
mod cli;
mod fuzz_regressions;
mod gltf;
#[cfg(feature = "view")]
mod gpu;
mod inputs;
mod lod;
mod materials;
mod metro;
mod octree;
mod options_v2;
mod ply_soup;
mod real_inputs;
mod reliability;
mod reliability_v2;
mod serve;
mod sharded;
mod signals;
mod simplify;
mod tiles;
mod view_core;
#[cfg(feature = "view")]
mod view_render;
#[cfg(feature = "view")]
mod web;
