pub use socdiff_engine::*;
