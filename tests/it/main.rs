//! Integration tests of scip2can, one binary: each module is one topic.

mod codec_props;
mod recordings;
