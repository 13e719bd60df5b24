//! What a web browser may do to the farm. A token-less farm on loopback trusts whoever can
//! reach it, and a browser reaches it on behalf of every page the user visits: these checks
//! keep such pages from driving it (cross-site requests), from reading it under a name of their
//! own (DNS rebinding) and from framing it.
//!
//! - [`guard`] answers only `Host` values the farm is reached by (IP literals, `localhost`, the
//!   names of `--allowed-host`) and refuses state-changing requests of other origins
//!   (`Origin`, `Sec-Fetch-Site`) unless `--allowed-origin` names them.
//! - [`security_headers`] puts `X-Frame-Options: DENY` and a `Content-Security-Policy` (with
//!   `frame-ancestors 'none'`) on every answer.
//!
//! Clients that are not browsers (curl, `tessera`, workers) send neither `Origin` nor
//! `Sec-Fetch-Site` and reach the farm by an address or a configured name: they see no change.

use axum::extract::State;
use axum::http::{HeaderMap, HeaderValue, Method, StatusCode, Uri, header};
use axum::response::{IntoResponse, Response};

use super::{AppError, AppState, auth};
use crate::state::Access;

/// The page's policy: its script, style sheet, pictures, videos and API calls come from the farm
/// itself, nothing runs inline, and no other site may frame it.
pub const CONTENT_SECURITY_POLICY: &str = "default-src 'none'; script-src 'self'; style-src 'self'; \
     img-src 'self'; media-src 'self'; connect-src 'self'; form-action 'self'; base-uri 'none'; frame-ancestors 'none'";

/// Longest part of a client's `Host` or `Origin` quoted back in a refusal.
const QUOTED: usize = 200;

/// An origin as browsers write it (`scheme://host[:port]`, lowercase, without the scheme's
/// default port), from what an operator or a request gives; `Err` says what is wrong with it.
/// `null` (the origin of sandboxed frames, files and some redirects) is not an origin here.
pub fn normalize_origin(given: &str) -> Result<String, String> {
    let s = given.trim().to_ascii_lowercase();
    let (scheme, rest) = s.split_once("://").ok_or_else(|| {
        format!("{given:?} is not an origin: write scheme://host[:port], e.g. https://farm.example")
    })?;
    let default_port = match scheme {
        "http" => "80",
        "https" => "443",
        _ => return Err(format!("{given:?} is not an http:// or https:// origin")),
    };
    let rest = rest.strip_suffix('/').unwrap_or(rest);
    if rest.is_empty() || rest.contains(['/', '?', '#', '@', ' ', '\\']) {
        return Err(format!(
            "{given:?} is not an origin: write scheme://host[:port] with no path, e.g. https://farm.example"
        ));
    }
    let (host, port) =
        split_host_port(rest).ok_or_else(|| format!("{given:?} has no valid host and port"))?;
    match port {
        Some(p) if p != default_port => Ok(format!("{scheme}://{host}:{p}")),
        _ => Ok(format!("{scheme}://{host}")),
    }
}

/// A host name for `--allowed-host`: lowercase, without a trailing dot; `*` stays `*`.
pub fn normalize_allowed_host(given: &str) -> Result<String, String> {
    let s = given.trim().to_ascii_lowercase();
    if s == "*" {
        return Ok(s);
    }
    let name = s.strip_suffix('.').unwrap_or(&s);
    let valid = !name.is_empty()
        && name.len() <= 253
        && name.split('.').all(|l| {
            !l.is_empty()
                && l.len() <= 63
                && l.bytes().all(|b| b.is_ascii_alphanumeric() || b == b'-' || b == b'_')
        });
    if !valid {
        return Err(format!(
            "{given:?} is not a host name: give a name such as farm.example (without scheme or port), or * for any"
        ));
    }
    Ok(name.to_string())
}

/// `host[:port]` split into the host (an `[IPv6]` literal kept in its brackets) and the port,
/// which must be a number; `None` if it does not parse.
fn split_host_port(s: &str) -> Option<(&str, Option<&str>)> {
    let (host, port) = if s.starts_with('[') {
        let end = s.find(']')?;
        let (host, after) = s.split_at(end + 1);
        match after {
            "" => (host, None),
            _ => (host, Some(after.strip_prefix(':')?)),
        }
    } else {
        match s.split_once(':') {
            Some((h, p)) => (h, Some(p)),
            None => (s, None),
        }
    };
    if host.is_empty() || port.is_some_and(|p| p.parse::<u16>().is_err()) {
        return None;
    }
    Some((host, port))
}

/// Whether the farm answers for `host` (a `Host` header): an IP literal (which no DNS
/// rebinding can produce), `localhost` and its subdomains (resolved by the machine itself), or
/// a name of `--allowed-host`.
pub fn host_allowed(access: &Access, host: &str) -> bool {
    if access.any_host {
        return true;
    }
    let Some((name, _)) = split_host_port(host.trim()) else {
        return false;
    };
    if let Some(v6) = name.strip_prefix('[').and_then(|n| n.strip_suffix(']')) {
        return v6.parse::<std::net::Ipv6Addr>().is_ok();
    }
    if name.parse::<std::net::Ipv4Addr>().is_ok() {
        return true;
    }
    let name = name.to_ascii_lowercase();
    let name = name.strip_suffix('.').unwrap_or(&name);
    name == "localhost" || name.ends_with(".localhost") || access.allowed_hosts.iter().any(|h| h == name)
}

/// The host a request names: its `Host` header, else the authority of its URI (HTTP/2).
fn request_host<'a>(headers: &'a HeaderMap, uri: &'a Uri) -> Option<&'a str> {
    match headers.get(header::HOST) {
        Some(h) => Some(h.to_str().unwrap_or("\u{fffd}")),
        None => uri.authority().map(|a| a.as_str()),
    }
}

/// Methods a page can use to change something: everything but reads (`GET`, `HEAD`) and
/// `OPTIONS`.
fn changes_state(method: &Method) -> bool {
    !matches!(*method, Method::GET | Method::HEAD | Method::OPTIONS)
}

/// Why a state-changing request from a browser is refused, if it is: an `Origin` that is not
/// the farm's own (its scheme, from `X-Forwarded-Proto` behind a proxy, else http, and its
/// `Host`) nor one of `--allowed-origin`, or a `Sec-Fetch-Site` of `cross-site` or `same-site`
/// without such an origin.
pub fn origin_refusal(
    access: &Access,
    headers: &HeaderMap,
    host: Option<&str>,
    method: &Method,
) -> Option<String> {
    if !changes_state(method) {
        return None;
    }
    let origin = headers.get(header::ORIGIN).map(|o| o.to_str().unwrap_or("\u{fffd}").trim());
    let fetch_site = headers.get("sec-fetch-site").and_then(|v| v.to_str().ok()).map(str::trim);
    let allow = "only the farm's own pages may change it; to let another site's pages do so, start the \
                 server with --allowed-origin ORIGIN (or TESSERA_ALLOWED_ORIGINS)";
    if let Some(origin) = origin {
        let quoted: String = origin.chars().take(QUOTED).collect();
        let Ok(normal) = normalize_origin(origin) else {
            if origin.eq_ignore_ascii_case("null") {
                return Some(format!(
                    "refused: a {method} from a page without an origin (\"Origin: null\": a sandboxed frame, a local \
                     file or a redirect) may not change this farm; {allow}"
                ));
            }
            return Some(format!(
                "refused: a {method} from the page at \"{quoted}\" may not change this farm; {allow}"
            ));
        };
        if access.allowed_origins.contains(&normal) {
            return None;
        }
        let scheme = headers
            .get("x-forwarded-proto")
            .and_then(|v| v.to_str().ok())
            .and_then(|v| v.split(',').next())
            .map(|v| v.trim().to_ascii_lowercase())
            .unwrap_or_else(|| "http".into());
        let own = host.and_then(|h| normalize_origin(&format!("{scheme}://{h}")).ok());
        if own.as_deref() == Some(normal.as_str()) {
            return None;
        }
        return Some(format!(
            "refused: a {method} from the page at \"{quoted}\" (another site) may not change this farm; {allow}"
        ));
    }
    if let Some(site) =
        fetch_site.filter(|s| s.eq_ignore_ascii_case("cross-site") || s.eq_ignore_ascii_case("same-site"))
    {
        return Some(format!(
            "refused: a {method} sent by a browser from another site (\"Sec-Fetch-Site: {site}\") may not change this \
             farm; {allow}"
        ));
    }
    None
}

/// Whether the request carries one of the farm's tokens in its `Authorization` header: a
/// client that has one is not a page that rebinds a name it controls to the farm (a page
/// cannot know the token), so the `Host` check leaves it alone.
fn holds_a_token(state: &AppState, headers: &HeaderMap) -> bool {
    let Some(given) = auth::bearer(headers) else {
        return false;
    };
    let settings = &state.settings;
    settings.api_token.as_deref().is_some_and(|t| auth::same_token(given, t))
        || auth::same_token(given, &settings.worker_token)
}

/// The `Host` check, then the `Origin` check, before anything else reads the request.
pub(super) async fn guard(
    State(state): State<AppState>,
    req: axum::extract::Request,
    next: axum::middleware::Next,
) -> Response {
    let access = &state.settings.access;
    let host = request_host(req.headers(), req.uri());
    let foreign_host = host.filter(|h| !host_allowed(access, h) && !holds_a_token(&state, req.headers()));
    if let Some(h) = foreign_host {
        let quoted: String = h.chars().take(QUOTED).collect();
        return AppError::new(
            StatusCode::MISDIRECTED_REQUEST,
            format!(
                "refused: this farm does not answer for the host \"{quoted}\" (a page may point a name of its own at \
                 it: DNS rebinding). Reach it by its IP address or localhost, or start the server with \
                 --allowed-host NAME (or TESSERA_ALLOWED_HOSTS) for each name its clients use"
            ),
        )
        .into_response();
    }
    if let Some(why) = origin_refusal(access, req.headers(), host, req.method()) {
        return AppError::new(StatusCode::FORBIDDEN, why).into_response();
    }
    next.run(req).await
}

/// Every answer: no framing by other sites, the page's content policy, no guessing of content
/// types, no referrer with a token in it, and no reading by other sites' pages.
pub(super) async fn security_headers(mut resp: Response) -> Response {
    let h = resp.headers_mut();
    h.insert(header::X_FRAME_OPTIONS, HeaderValue::from_static("DENY"));
    h.insert(header::CONTENT_SECURITY_POLICY, HeaderValue::from_static(CONTENT_SECURITY_POLICY));
    h.insert(header::X_CONTENT_TYPE_OPTIONS, HeaderValue::from_static("nosniff"));
    h.insert(header::REFERRER_POLICY, HeaderValue::from_static("no-referrer"));
    h.insert("cross-origin-resource-policy", HeaderValue::from_static("same-origin"));
    resp
}

#[cfg(test)]
mod tests {
    use super::*;

    fn access(origins: &[&str], hosts: &[&str]) -> Access {
        Access {
            allowed_origins: origins.iter().map(|o| normalize_origin(o).unwrap()).collect(),
            allowed_hosts: hosts.iter().map(|h| normalize_allowed_host(h).unwrap()).collect(),
            any_host: hosts.contains(&"*"),
            public_metrics: false,
        }
    }

    #[test]
    fn origins_are_normalized_as_browsers_write_them() {
        assert_eq!(normalize_origin("HTTPS://Farm.Example:443/").unwrap(), "https://farm.example");
        assert_eq!(normalize_origin("http://farm.example:80").unwrap(), "http://farm.example");
        assert_eq!(normalize_origin("http://127.0.0.1:8080").unwrap(), "http://127.0.0.1:8080");
        assert_eq!(normalize_origin("http://[::1]:8080").unwrap(), "http://[::1]:8080");
        for bad in [
            "null",
            "*",
            "farm.example",
            "ftp://x",
            "https://",
            "https://x/y",
            "https://x:99999",
            "https://u@x",
        ] {
            assert!(normalize_origin(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn hosts_answered_are_addresses_localhost_and_named_ones() {
        let a = access(&[], &["farm.example"]);
        for ok in [
            "127.0.0.1:8080",
            "10.0.0.5",
            "[::1]:8080",
            "localhost:8080",
            "LOCALHOST.",
            "x.localhost",
            "Farm.Example:8080",
        ] {
            assert!(host_allowed(&a, ok), "{ok}");
        }
        for bad in
            ["rebind.evil.example", "rebind.evil.example:8080", "farm.example.evil", "", "[nope]", "a:b"]
        {
            assert!(!host_allowed(&a, bad), "{bad}");
        }
        assert!(host_allowed(&access(&[], &["*"]), "rebind.evil.example"));
        assert!(normalize_allowed_host("farm.example:8080").is_err());
        assert!(normalize_allowed_host("http://farm.example").is_err());
    }

    #[test]
    fn state_changing_requests_of_other_origins_are_refused() {
        let a = access(&["https://ui.example"], &[]);
        let host = Some("127.0.0.1:8080");
        let with = |pairs: &[(&str, &str)]| {
            let mut h = HeaderMap::new();
            for (k, v) in pairs {
                h.insert(
                    axum::http::HeaderName::from_bytes(k.as_bytes()).unwrap(),
                    HeaderValue::from_str(v).unwrap(),
                );
            }
            h
        };
        let refused = |h: &HeaderMap, m: Method| origin_refusal(&a, h, host, &m);
        assert!(refused(&with(&[]), Method::POST).is_none());
        assert!(refused(&with(&[("origin", "http://127.0.0.1:8080")]), Method::POST).is_none());
        assert!(
            refused(
                &with(&[("origin", "https://ui.example"), ("sec-fetch-site", "cross-site")]),
                Method::POST
            )
            .is_none()
        );
        assert!(refused(&with(&[("origin", "https://evil.example")]), Method::GET).is_none());
        for h in [
            with(&[("origin", "https://evil.example")]),
            with(&[("origin", "null")]),
            with(&[("origin", "https://127.0.0.1:8080")]),
            with(&[("sec-fetch-site", "cross-site")]),
            with(&[("sec-fetch-site", "same-site")]),
        ] {
            for m in [Method::POST, Method::PUT, Method::DELETE, Method::PATCH] {
                let e = refused(&h, m).unwrap();
                assert!(e.contains("--allowed-origin"), "{e}");
            }
        }
        // Behind a TLS proxy that says so, the https origin of the same host is the farm's own.
        let h = with(&[("origin", "https://127.0.0.1:8080"), ("x-forwarded-proto", "https")]);
        assert!(refused(&h, Method::POST).is_none());
    }
}
