//! Integration tests of scip2can, one binary: each module is one topic.

mod bridge_replay;
mod can_tools;
mod codec_props;
mod emulate_e2e;
mod icount;
mod live_bridge;
mod qemu;
mod recordings;
mod replay_model;
mod sim_clients;
mod sim_protocol;
mod time_sync;
