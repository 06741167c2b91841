//! Integration tests of scip2can, one binary: each module is one topic.

mod bridge_replay;
mod can_tools;
mod codec_props;
mod emulate_e2e;
mod emulate_eth;
mod host_streaming;
mod host_time_master;
mod icount;
mod live_bridge;
mod live_view;
mod lossless_replay;
mod mcap_view;
mod noise;
mod pipeline_blocks;
mod pp_faults;
mod qemu;
mod qemu_time_estimate;
mod recordings;
mod replay_model;
mod scan_clock;
mod session_timing;
mod sim_clients;
mod sim_protocol;
mod time_sync;
