//! texsyn: exact multi-scale block texture synthesis after Stahlhut, with the
//! nearest-neighbour search on this machine or on a cluster of workers.

pub mod search;
