//! placeholder during bootstrap
#![deny(missing_docs)]
