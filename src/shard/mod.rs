//! Sharded build: a static spatial split into shards, each built on its
//! own (any machine, any scheduler: the CLI is the contract), then a merge
//! that builds the shared top — the way Entwine's subset builds and Cesium
//! ion's tiling jobs scale out, with the mesh's top re-simplified from the
//! shards' coarsest levels.
//!
//! Takes: the input mesh (any format the soup stage reads) and a plan.
//! Gives: `plan` → `PLAN.json` ([`mod@plan`]); `build --plan --shard I` → one
//! shard directory ([`mod@build`], [`state`]); `merge` → one store that every
//! command opens like a monolithic build's ([`mod@merge`]).
//!
//! Invariants: a position that two shards hold is locked in both at every
//! shard level, so the union of their levels is closed where the input
//! is; every file names the plan's id, and the merge takes only shards of
//! its plan, each once, all present. Design and figures: `docs/sharded.md`.

pub mod build;
pub mod merge;
pub mod plan;
pub mod state;

pub use build::{build_shard, ShardOptions, ShardReport};
pub use merge::{merge, MergeOptions, MergeReport};
pub use plan::{plan, Plan, PlanOptions};
