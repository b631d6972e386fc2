//! Synthetic containers for tests.
