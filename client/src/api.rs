//! The job API over HTTP (blocking, ureq): what the client asks the server, and the server's
//! errors (`tessera::protocol::ApiError`) turned into messages people can act on.

use std::io::Read;
use std::time::Duration;

use serde::de::DeserializeOwned;
use tessera::protocol::{
    ApiError, JobInfo, JobList, JobLog, JobRequest, MissingFilesRequest, MissingFilesResponse, Problem,
};

/// Where the client talks to, and with which token.
pub struct Api {
    pub base: String,
    token: Option<String>,
    agent: ureq::Agent,
    /// Where the server and token came from, for the hints in messages.
    pub config_hint: String,
}

/// Why a request failed.
#[derive(Debug)]
pub enum CallError {
    /// The server answered with an error status; its message is readable as it is.
    Status { code: u16, message: String },
    /// The server could not be reached (or the connection broke).
    Transport(String),
}

impl std::fmt::Display for CallError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            CallError::Status { message, .. } | CallError::Transport(message) => write!(f, "{message}"),
        }
    }
}

impl std::error::Error for CallError {}

/// `file:line: element: message`, with what the problem knows.
pub fn format_problem(p: &Problem) -> String {
    let mut out = String::new();
    if let Some(file) = &p.file {
        out.push_str(file);
        if let Some(line) = p.line {
            out.push_str(&format!(":{line}"));
        }
        out.push_str(": ");
    }
    if let Some(el) = &p.element {
        out.push_str(&format!("<{el}>: "));
    }
    out.push_str(&p.message);
    out
}

/// The server's error as lines: the headline, then one `file:line: element: message` line per
/// problem (a headline that already ends with the problem's text is not repeated).
pub fn format_api_error(e: &ApiError) -> String {
    let mut head = e.error.clone();
    let lines: Vec<String> = e.problems.iter().map(format_problem).collect();
    for l in &lines {
        if let Some(stripped) = head.strip_suffix(l.as_str()) {
            head = stripped.trim_end().trim_end_matches(':').to_string();
        }
    }
    let mut out = head;
    for l in lines {
        out.push_str("\n  ");
        out.push_str(&l);
    }
    out
}

impl Api {
    pub fn new(base: String, token: Option<String>, config_hint: String) -> Api {
        let agent = ureq::AgentBuilder::new()
            .timeout_connect(Duration::from_secs(10))
            // Submissions are validated before the answer (every asset loaded), and long polls
            // are not used: minutes are generous for any one answer.
            .timeout_read(Duration::from_secs(600))
            .timeout_write(Duration::from_secs(600))
            .build();
        Api { base, token, agent, config_hint }
    }

    fn request(&self, method: &str, path: &str) -> ureq::Request {
        let req = self.agent.request(method, &format!("{}{path}", self.base));
        match &self.token {
            Some(t) => req.set("Authorization", &format!("Bearer {t}")),
            None => req,
        }
    }

    /// The error of a failed call, explained.
    fn explain(&self, what: &str, e: ureq::Error) -> CallError {
        match e {
            ureq::Error::Status(code, resp) => {
                let body = resp.into_string().unwrap_or_default();
                let detail = match serde_json::from_str::<ApiError>(&body) {
                    Ok(api) => format_api_error(&api),
                    Err(_) if body.trim().is_empty() => "no explanation given".to_string(),
                    Err(_) => body.trim().chars().take(2000).collect(),
                };
                let hint = match code {
                    401 | 403 => format!(
                        "\n  the farm needs its API token: pass --token, set TESSERA_TOKEN, or put token = \"...\" in {}",
                        self.config_hint
                    ),
                    _ => String::new(),
                };
                CallError::Status {
                    code,
                    message: format!("{what}: the server answered {code}: {detail}{hint}"),
                }
            }
            ureq::Error::Transport(t) if self.base.starts_with("https://") => CallError::Transport(format!(
                "{what}: cannot reach the server at {}: {t}; {} (choose the server with --server, TESSERA_SERVER or server = \"...\" in {})",
                self.base,
                tessera::protocol::HTTPS_HINT,
                self.config_hint
            )),
            ureq::Error::Transport(t) => CallError::Transport(format!(
                "{what}: cannot reach the server at {}: {t}; is tessera-server running there? (choose the server with --server, TESSERA_SERVER or server = \"...\" in {})",
                self.base, self.config_hint
            )),
        }
    }

    fn json<T: DeserializeOwned>(&self, what: &str, resp: ureq::Response) -> Result<T, CallError> {
        let text = resp
            .into_string()
            .map_err(|e| CallError::Transport(format!("{what}: the answer broke off: {e}")))?;
        serde_json::from_str(&text).map_err(|e| {
            CallError::Transport(format!(
                "{what}: the server's answer is not what this client understands ({e}); is {} a tessera-server of the same version?",
                self.base
            ))
        })
    }

    pub fn get_json<T: DeserializeOwned>(&self, what: &str, path: &str) -> Result<T, CallError> {
        let resp = self.request("GET", path).call().map_err(|e| self.explain(what, e))?;
        self.json(what, resp)
    }

    pub fn job(&self, id: u64) -> Result<JobInfo, CallError> {
        self.get_json(&format!("job {id}"), &format!("/api/v1/jobs/{id}"))
    }

    pub fn jobs(&self) -> Result<JobList, CallError> {
        self.get_json("listing the jobs", "/api/v1/jobs")
    }

    pub fn log(&self, id: u64, after: u64) -> Result<JobLog, CallError> {
        self.get_json(&format!("the log of job {id}"), &format!("/api/v1/jobs/{id}/log?after={after}"))
    }

    pub fn cancel(&self, id: u64) -> Result<JobInfo, CallError> {
        let what = format!("cancelling job {id}");
        let resp = self
            .request("POST", &format!("/api/v1/jobs/{id}/cancel"))
            .send_bytes(&[])
            .map_err(|e| self.explain(&what, e))?;
        self.json(&what, resp)
    }

    /// `DELETE /api/v1/jobs/ID`: a finished job and its files.
    pub fn delete(&self, id: u64) -> Result<(), CallError> {
        let what = format!("deleting job {id}");
        self.request("DELETE", &format!("/api/v1/jobs/{id}")).call().map_err(|e| self.explain(&what, e))?;
        Ok(())
    }

    /// A change of job `id` (`POST .../pause`, `PATCH` with a body, ...): `method` on
    /// `/api/v1/jobs/{id}{tail}` with `body` as JSON (`None`: an empty body); the job as it is now.
    pub fn change_job(
        &self,
        what: &str,
        method: &str,
        path: &str,
        body: Option<&serde_json::Value>,
    ) -> Result<JobInfo, CallError> {
        let req = self.request(method, path);
        let sent = match body {
            Some(b) => req.set("Content-Type", "application/json").send_string(&b.to_string()),
            None => req.send_bytes(&[]),
        };
        let resp = sent.map_err(|e| self.explain(what, e))?;
        self.json(what, resp)
    }

    pub fn workers(&self) -> Result<tessera::protocol::WorkerList, CallError> {
        self.get_json("listing the workers", "/api/v1/workers")
    }

    /// `POST /api/v1/workers/ID/ACTION` (`drain`, `disable` or `enable`).
    pub fn worker_action(&self, id: u64, action: &str) -> Result<tessera::protocol::WorkerInfo, CallError> {
        let what = format!("{action} worker {id}");
        let resp = self
            .request("POST", &format!("/api/v1/workers/{id}/{action}"))
            .send_bytes(&[])
            .map_err(|e| self.explain(&what, e))?;
        self.json(&what, resp)
    }

    /// The bytes at `url` (a path on the server, as the API gives them).
    pub fn download(&self, what: &str, url: &str) -> Result<Vec<u8>, CallError> {
        let resp = self.request("GET", url).call().map_err(|e| self.explain(what, e))?;
        let mut out = Vec::new();
        resp.into_reader()
            .read_to_end(&mut out)
            .map_err(|e| CallError::Transport(format!("{what}: the download broke off: {e}")))?;
        Ok(out)
    }

    /// `POST /api/v1/jobs` with a multipart body read from `body` (`length` bytes).
    pub fn submit(&self, content_type: &str, length: u64, body: impl Read) -> Result<JobInfo, CallError> {
        let what = "submitting the job";
        let resp = self
            .request("POST", "/api/v1/jobs")
            .set("Content-Type", content_type)
            .set("Content-Length", &length.to_string())
            .send(body)
            .map_err(|e| self.explain(what, e))?;
        self.json(what, resp)
    }
}

impl Api {
    /// `POST /api/v1/files/missing`: which of these files the server lacks.
    pub fn missing_files(&self, req: &MissingFilesRequest) -> Result<MissingFilesResponse, CallError> {
        let what = "asking the server which files it lacks";
        let body = serde_json::to_string(req).map_err(|e| CallError::Transport(format!("{what}: {e}")))?;
        let resp = self
            .request("POST", "/api/v1/files/missing")
            .set("Content-Type", "application/json")
            .send_string(&body)
            .map_err(|e| self.explain(what, e))?;
        self.json(what, resp)
    }

    /// `PUT /api/v1/files/{sha256}` with `size` bytes read from `body`.
    pub fn put_file(&self, what: &str, sha256: &str, size: u64, body: impl Read) -> Result<(), CallError> {
        self.request("PUT", &format!("/api/v1/files/{sha256}"))
            .set("Content-Type", "application/octet-stream")
            .set("Content-Length", &size.to_string())
            .send(body)
            .map_err(|e| self.explain(what, e))?;
        Ok(())
    }

    /// `POST /api/v1/jobs` with a JSON [`JobRequest`] (its files already on the server).
    pub fn submit_json(&self, req: &JobRequest) -> Result<JobInfo, CallError> {
        let what = "submitting the job";
        let body = serde_json::to_string(req).map_err(|e| CallError::Transport(format!("{what}: {e}")))?;
        let resp = self
            .request("POST", "/api/v1/jobs")
            .set("Content-Type", "application/json")
            .send_string(&body)
            .map_err(|e| self.explain(what, e))?;
        self.json(what, resp)
    }
}

/// A multipart/form-data body: text fields, then one file field. Returns the content type, the
/// part before the file's bytes and the part after them (so the file can be streamed between).
pub fn multipart_frame(
    fields: &[(&str, String)],
    file_field: &str,
    file_name: &str,
) -> (String, Vec<u8>, Vec<u8>) {
    let nanos =
        std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_nanos());
    let boundary = format!("tessera-client-{:x}-{nanos:x}", std::process::id());
    let mut head = Vec::new();
    for (name, value) in fields {
        head.extend_from_slice(
            format!("--{boundary}\r\nContent-Disposition: form-data; name=\"{name}\"\r\n\r\n{value}\r\n")
                .as_bytes(),
        );
    }
    head.extend_from_slice(
        format!(
            "--{boundary}\r\nContent-Disposition: form-data; name=\"{file_field}\"; filename=\"{file_name}\"\r\nContent-Type: application/octet-stream\r\n\r\n"
        )
        .as_bytes(),
    );
    let tail = format!("\r\n--{boundary}--\r\n").into_bytes();
    (format!("multipart/form-data; boundary={boundary}"), head, tail)
}

/// Whether an error is worth retrying while following a job (the server restarting).
pub fn is_transient(e: &CallError) -> bool {
    matches!(e, CallError::Transport(_) | CallError::Status { code: 502..=504, .. })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn problems_are_one_line_each_and_not_repeated() {
        let e = ApiError {
            error: "the scene cannot be rendered: s.xml:7: <Mesh id=\"2\">: cannot read PLY file x.ply"
                .into(),
            problems: vec![Problem {
                file: Some("s.xml".into()),
                line: Some(7),
                element: Some("Mesh id=\"2\"".into()),
                message: "cannot read PLY file x.ply".into(),
            }],
        };
        assert_eq!(
            format_api_error(&e),
            "the scene cannot be rendered\n  s.xml:7: <Mesh id=\"2\">: cannot read PLY file x.ply"
        );
        let e = ApiError {
            error: "two problems".into(),
            problems: vec![
                Problem { file: None, line: None, element: None, message: "first".into() },
                Problem { file: Some("a.json".into()), line: None, element: None, message: "second".into() },
            ],
        };
        assert_eq!(format_api_error(&e), "two problems\n  first\n  a.json: second");
        let plain = ApiError { error: "there is no job 9".into(), problems: vec![] };
        assert_eq!(format_api_error(&plain), "there is no job 9");
    }

    #[test]
    fn multipart_frames_a_file() {
        let (ct, head, tail) = multipart_frame(&[("priority", "5".into())], "bundle", "s.tar.gz");
        let boundary = ct.strip_prefix("multipart/form-data; boundary=").unwrap();
        let head = String::from_utf8(head).unwrap();
        assert!(head.starts_with(&format!(
            "--{boundary}\r\nContent-Disposition: form-data; name=\"priority\"\r\n\r\n5\r\n"
        )));
        assert!(head.ends_with("filename=\"s.tar.gz\"\r\nContent-Type: application/octet-stream\r\n\r\n"));
        assert_eq!(tail, format!("\r\n--{boundary}--\r\n").into_bytes());
    }
}
