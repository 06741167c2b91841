//! Placeholder, replaced by the golden-file tests.
