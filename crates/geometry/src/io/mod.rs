//! File input and output at the edge of the crate. Algorithms elsewhere in `geometry` never
//! open files; these modules do nothing else.

pub mod atomic;
