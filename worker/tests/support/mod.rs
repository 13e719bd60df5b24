//! What the worker's end-to-end tests share: running the real binary and reading its output.

use std::process::{Command, Output};

pub const BIN: &str = env!("CARGO_BIN_EXE_tessera-worker");

/// The outcome of one run of the binary.
pub struct Run {
    pub code: Option<i32>,
    pub stdout: String,
    pub stderr: String,
}

impl Run {
    /// Everything about the run, for assertion messages.
    pub fn describe(&self) -> String {
        format!("exit {:?}\n--- stdout ---\n{}\n--- stderr ---\n{}", self.code, self.stdout, self.stderr)
    }
}

/// Runs `tessera-worker` with `args` and waits for it.
pub fn run<S: AsRef<std::ffi::OsStr>>(args: &[S]) -> Run {
    run_with_env(args, &[])
}

/// [`run`] with environment variables `env` set for the run.
#[allow(dead_code)] // not every test binary that includes this module sets any
pub fn run_with_env<S: AsRef<std::ffi::OsStr>>(args: &[S], env: &[(&str, &str)]) -> Run {
    let Output { status, stdout, stderr } =
        Command::new(BIN).args(args).envs(env.iter().copied()).output().expect("spawn tessera-worker");
    Run {
        code: status.code(),
        stdout: String::from_utf8_lossy(&stdout).into_owned(),
        stderr: String::from_utf8_lossy(&stderr).into_owned(),
    }
}
