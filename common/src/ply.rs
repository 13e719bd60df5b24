//! PLY reader. Being written.
