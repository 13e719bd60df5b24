//! Where the farm is and how to get in: the server URL and the API token, from a flag, else an
//! environment variable (`TESSERA_SERVER`, `TESSERA_TOKEN`; clap reads both into the same
//! option), else the config file, else the defaults (`http://127.0.0.1:8080`, no token).
//!
//! The config file is `$XDG_CONFIG_HOME/tessera/client.toml` (or `~/.config/tessera/client.toml`),
//! or the one `--config` / `TESSERA_CONFIG` names. It is a tiny subset of TOML:
//!
//! ```toml
//! # the farm
//! server = "http://farm.example:8080"
//! token = "..."
//! ```

use std::path::{Path, PathBuf};

use anyhow::{Result, bail};

/// The server when nothing names one: `tessera-server`'s default address.
pub const DEFAULT_SERVER: &str = "http://127.0.0.1:8080";

/// What the config file says.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct FileConfig {
    pub server: Option<String>,
    pub token: Option<String>,
}

/// The server and token to use, and where each came from (for messages).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Resolved {
    pub server: String,
    pub token: Option<String>,
    /// The config file that was read, if one exists.
    pub config_file: Option<PathBuf>,
}

/// The default config file: `$XDG_CONFIG_HOME/tessera/client.toml`, else
/// `$HOME/.config/tessera/client.toml`. `None` without either variable.
pub fn default_config_path(xdg_config_home: Option<&str>, home: Option<&str>) -> Option<PathBuf> {
    // The XDG spec ignores a relative (or empty) XDG_CONFIG_HOME.
    if let Some(x) = xdg_config_home.filter(|x| Path::new(x).is_absolute()) {
        return Some(Path::new(x).join("tessera/client.toml"));
    }
    home.filter(|h| !h.is_empty()).map(|h| Path::new(h).join(".config/tessera/client.toml"))
}

/// Parses the config file's text; `path` names it in messages.
pub fn parse_config(text: &str, path: &Path) -> Result<FileConfig> {
    let mut cfg = FileConfig::default();
    for (i, raw) in text.lines().enumerate() {
        let line = raw.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let at = format!("{}:{}", path.display(), i + 1);
        let Some((key, value)) = line.split_once('=') else {
            bail!("{at}: expected `key = \"value\"`, found {line:?}; the keys are server and token");
        };
        let key = key.trim();
        let value = parse_string(value.trim()).map_err(|e| anyhow::anyhow!("{at}: {key}: {e}"))?;
        let slot = match key {
            "server" => &mut cfg.server,
            "token" => &mut cfg.token,
            other => bail!("{at}: unknown key {other:?}; the keys are server and token"),
        };
        if slot.is_some() {
            bail!("{at}: {key} is given twice");
        }
        *slot = Some(value);
    }
    Ok(cfg)
}

/// A TOML string value: "basic" (with \" \\ \n \t escapes) or 'literal', then an optional
/// `# comment`; a bare word is taken as it is.
fn parse_string(value: &str) -> Result<String, String> {
    let rest_is_comment = |rest: &str| {
        let rest = rest.trim();
        if rest.is_empty() || rest.starts_with('#') {
            Ok(())
        } else {
            Err(format!("unexpected {rest:?} after the value"))
        }
    };
    if let Some(body) = value.strip_prefix('"') {
        let mut out = String::new();
        let mut chars = body.char_indices();
        while let Some((i, c)) = chars.next() {
            match c {
                '"' => {
                    rest_is_comment(&body[i + 1..])?;
                    return Ok(out);
                }
                '\\' => match chars.next().map(|(_, c)| c) {
                    Some('"') => out.push('"'),
                    Some('\\') => out.push('\\'),
                    Some('n') => out.push('\n'),
                    Some('t') => out.push('\t'),
                    Some(c) => return Err(format!("unknown escape \\{c} in the string")),
                    None => break,
                },
                c => out.push(c),
            }
        }
        return Err("the string has no closing \"".into());
    }
    if let Some(body) = value.strip_prefix('\'') {
        let end = body.find('\'').ok_or("the string has no closing '")?;
        rest_is_comment(&body[end + 1..])?;
        return Ok(body[..end].to_string());
    }
    let word = value.split('#').next().unwrap_or("").trim();
    if word.is_empty() {
        return Err("the value is empty; write it in quotes, e.g. server = \"http://farm:8080\"".into());
    }
    Ok(word.to_string())
}

/// The server URL as given, with `http://` added when it has no scheme, without a trailing
/// `/` and without the API's path (`/api/v1`, with a note on stderr that says so:
/// [`tessera::protocol::server_base_url`]).
pub fn normalize_server(url: &str) -> Result<String> {
    let (base, note) =
        tessera::protocol::server_base_url(url).map_err(|e| anyhow::anyhow!("--server: {e}"))?;
    if let Some(note) = note {
        eprintln!("{note}");
    }
    Ok(base)
}

/// Flags (and the environment, which clap folds into them) beat the config file, which beats
/// the defaults. `config` is the file named by `--config`/`TESSERA_CONFIG` (it must exist), or
/// the default path (read when it exists).
pub fn resolve(
    server_flag: Option<&str>,
    token_flag: Option<&str>,
    config: Option<&Path>,
    default_config: Option<PathBuf>,
) -> Result<Resolved> {
    let (file, config_file) = match (config, default_config) {
        (Some(p), _) => {
            let text = std::fs::read_to_string(p).map_err(|e| {
                anyhow::anyhow!(
                    "{}: cannot read the config file (--config, TESSERA_CONFIG): {e}",
                    p.display()
                )
            })?;
            (parse_config(&text, p)?, Some(p.to_path_buf()))
        }
        (None, Some(p)) => match std::fs::read_to_string(&p) {
            Ok(text) => (parse_config(&text, &p)?, Some(p)),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => (FileConfig::default(), None),
            Err(e) => bail!("{}: cannot read the config file: {e}", p.display()),
        },
        (None, None) => (FileConfig::default(), None),
    };
    if let (Some(p), Some(_)) = (&config_file, &file.token) {
        warn_if_others_can_read(p);
    }
    let server =
        server_flag.map(str::to_string).or(file.server).unwrap_or_else(|| DEFAULT_SERVER.to_string());
    let token = token_flag.map(str::to_string).or(file.token).filter(|t| !t.is_empty());
    Ok(Resolved { server: normalize_server(&server)?, token, config_file })
}

/// A token in a file others can read is a token others have.
fn warn_if_others_can_read(path: &Path) {
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        if let Ok(meta) = std::fs::metadata(path)
            && meta.permissions().mode() & 0o077 != 0
        {
            eprintln!(
                "warning: {} holds a token and other users can read it; chmod 600 {}",
                path.display(),
                path.display()
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_the_small_toml_subset() {
        let p = Path::new("client.toml");
        let cfg = parse_config("# farm\n\nserver = \"http://farm:8080\"  # the farm\ntoken='s3cr\"et'\n", p)
            .unwrap();
        assert_eq!(cfg.server.as_deref(), Some("http://farm:8080"));
        assert_eq!(cfg.token.as_deref(), Some("s3cr\"et"));
        let cfg = parse_config("server = farm:9000\ntoken = \"a\\\\b\\\"c\"", p).unwrap();
        assert_eq!(cfg.server.as_deref(), Some("farm:9000"));
        assert_eq!(cfg.token.as_deref(), Some("a\\b\"c"));
    }

    #[test]
    fn config_mistakes_name_the_line() {
        let p = Path::new("/home/u/.config/tessera/client.toml");
        let e = parse_config("server = \"x\"\nsevrer = \"y\"\n", p).unwrap_err().to_string();
        assert!(e.starts_with("/home/u/.config/tessera/client.toml:2: unknown key \"sevrer\""), "{e}");
        let e = parse_config("token = \"abc\n", p).unwrap_err().to_string();
        assert!(e.contains(":1: token: the string has no closing"), "{e}");
        let e = parse_config("server\n", p).unwrap_err().to_string();
        assert!(e.contains(":1: expected `key = \"value\"`"), "{e}");
        let e = parse_config("server = \"a\"\nserver = \"b\"\n", p).unwrap_err().to_string();
        assert!(e.contains(":2: server is given twice"), "{e}");
        let e = parse_config("server = \"a\" b\n", p).unwrap_err().to_string();
        assert!(e.contains("unexpected \"b\" after the value"), "{e}");
    }

    #[test]
    fn default_path_follows_xdg() {
        assert_eq!(
            default_config_path(Some("/x"), Some("/home/u")),
            Some(PathBuf::from("/x/tessera/client.toml"))
        );
        assert_eq!(
            default_config_path(Some("relative"), Some("/home/u")),
            Some(PathBuf::from("/home/u/.config/tessera/client.toml"))
        );
        assert_eq!(
            default_config_path(None, Some("/home/u")),
            default_config_path(Some(""), Some("/home/u"))
        );
        assert_eq!(default_config_path(None, None), None);
    }

    #[test]
    fn flags_beat_the_file_which_beats_the_defaults() {
        let dir = tessera_testkit::TempDir::new("client-config");
        let file = dir.write("client.toml", "server = \"farm:8080/\"\ntoken = \"from-file\"\n");
        let r = resolve(None, None, None, Some(file.clone())).unwrap();
        assert_eq!((r.server.as_str(), r.token.as_deref()), ("http://farm:8080", Some("from-file")));
        assert_eq!(r.config_file.as_deref(), Some(file.as_path()));
        let r = resolve(Some("https://other"), Some("flag"), None, Some(file.clone())).unwrap();
        assert_eq!((r.server.as_str(), r.token.as_deref()), ("https://other", Some("flag")));
        // No file at the default path: the defaults.
        let r = resolve(None, None, None, Some(dir.join("absent.toml"))).unwrap();
        assert_eq!((r.server.as_str(), r.token, r.config_file), (DEFAULT_SERVER, None, None));
        // A file named explicitly must exist.
        let e = resolve(None, None, Some(&dir.join("absent.toml")), None).unwrap_err().to_string();
        assert!(e.contains("absent.toml: cannot read the config file (--config, TESSERA_CONFIG)"), "{e}");
    }
}
