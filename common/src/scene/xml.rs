//! XML front end (2020/21 dialect). Being written.
