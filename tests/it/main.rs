//! Integration tests of scip2can, one binary: each module is one topic.

mod recordings;
