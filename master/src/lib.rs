//! texsyn master library.
