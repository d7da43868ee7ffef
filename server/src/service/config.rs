//! `lightfarm serve` configuration: the listen address, the data directory, the teams and their
//! bearer tokens, and the limits. Read from a TOML file (`--config`); without one the service
//! runs open for a single local user ([`ServiceConfig::open_local`]), and a file with
//! `open = true` (and no teams) does the same with its own limits.
//!
//! Invariants:
//! - An open (token-less) configuration only ever listens on a loopback address; [`check_bind`]
//!   refuses anything else before a socket is opened.
//! - Team names are unique, non-empty and safe as directory names; tokens are non-empty and
//!   unique across teams. Only each token's BLAKE3 hash is kept in memory after loading.

use std::net::SocketAddr;
use std::path::{Path, PathBuf};

use serde::Deserialize;

/// Default listen address.
pub const DEFAULT_ADDR: &str = "127.0.0.1:8080";
/// Default data directory.
pub const DEFAULT_DATA: &str = "./lightfarm-data";
/// The team every request belongs to in open mode.
pub const LOCAL_TEAM: &str = "local";

/// Why a configuration was refused.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("config {path}: {message}")]
    Read { path: PathBuf, message: String },
    #[error("config: {0}")]
    Invalid(String),
    #[error(
        "refusing to listen on {0} without --config: an open service (no tokens) only listens on \
         loopback; pass --config with [[teams]] tokens to serve other machines"
    )]
    OpenOnNonLoopback(SocketAddr),
}

/// Limits on what one request or one bake may ask for.
#[derive(Clone, Debug, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Limits {
    /// Largest request body (assets, scenes), bytes. Larger → 413.
    pub max_body_bytes: usize,
    /// Most triangles in one uploaded mesh. More → 413.
    pub max_triangles: u64,
    /// Most texels in one bake (at its effective `texels_per_face`). More → 422.
    pub max_texels: u64,
    /// Most rays in one bake (texels × rays_per_texel). More → 422.
    pub max_rays_per_bake: u64,
    /// Bakes waiting to run; one more → 429 with Retry-After.
    pub queue_capacity: usize,
    /// Bakes running at once (they share one worker pool).
    pub concurrent_bakes: usize,
    /// Worker-pool threads (0: one per core).
    pub worker_threads: usize,
    /// Requests that take longer are answered 408 (SSE streams and downloads are not cut).
    pub request_timeout_seconds: u64,
    /// The blob store (assets, scenes, bundles) is trimmed least-recently-used to this size.
    pub store_budget_bytes: u64,
    /// The operator cache (shape operators, DRT rays, transports, DNRT grids) is trimmed
    /// least-recently-used to this size after every bake.
    pub operator_cache_bytes: u64,
}

/// Default byte budget of an operator cache: the service's and a farm worker's.
pub const DEFAULT_OPERATOR_CACHE_BYTES: u64 = 10 << 30;

impl Default for Limits {
    fn default() -> Limits {
        Limits {
            max_body_bytes: 64 << 20,
            max_triangles: 2_000_000,
            max_texels: 4_000_000,
            max_rays_per_bake: 20_000_000_000,
            queue_capacity: 64,
            concurrent_bakes: 2,
            worker_threads: 0,
            request_timeout_seconds: 30,
            store_budget_bytes: 20 << 30,
            operator_cache_bytes: DEFAULT_OPERATOR_CACHE_BYTES,
        }
    }
}

/// One team and its tokens, as written in the file.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct TeamEntry {
    name: String,
    #[serde(default)]
    token: Option<String>,
    #[serde(default)]
    tokens: Vec<String>,
}

/// The file as written.
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct ConfigFile {
    addr: Option<String>,
    data: Option<PathBuf>,
    farm: Option<String>,
    /// Open local mode with the file's limits (no `[[teams]]`; loopback only).
    #[serde(default)]
    open: bool,
    #[serde(default)]
    limits: Limits,
    #[serde(default)]
    teams: Vec<TeamEntry>,
}

/// A team allowed to call the API.
#[derive(Clone, Debug)]
pub struct Team {
    pub name: String,
    /// BLAKE3 hashes of the team's bearer tokens.
    pub token_hashes: Vec<[u8; 32]>,
}

/// The whole service configuration.
#[derive(Clone, Debug)]
pub struct ServiceConfig {
    pub addr: SocketAddr,
    pub data: PathBuf,
    pub limits: Limits,
    /// Empty: open mode (every request is team [`LOCAL_TEAM`], no token needed).
    pub teams: Vec<Team>,
    /// `nats://HOST:PORT` of a bake farm: jobs and blobs live in NATS JetStream and bakes run on
    /// `lightfarm worker`s ([`super::farm`]). `None`: the embedded queue and store.
    pub farm: Option<String>,
}

impl ServiceConfig {
    /// No tokens, default limits.
    pub fn open_local(addr: SocketAddr, data: PathBuf) -> ServiceConfig {
        ServiceConfig {
            addr,
            data,
            limits: Limits::default(),
            teams: Vec::new(),
            farm: None,
        }
    }

    /// Reads a TOML file. `addr` and `data` in the file are defaults the CLI may override.
    pub fn from_file(path: &Path) -> Result<ServiceConfig, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|e| ConfigError::Read {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
        ServiceConfig::from_toml(&text).map_err(|e| match e {
            ConfigError::Invalid(message) => ConfigError::Read {
                path: path.to_path_buf(),
                message,
            },
            other => other,
        })
    }

    /// Parses the TOML text of a configuration file.
    pub fn from_toml(text: &str) -> Result<ServiceConfig, ConfigError> {
        let file: ConfigFile =
            toml::from_str(text).map_err(|e| ConfigError::Invalid(e.to_string()))?;
        let addr = file
            .addr
            .as_deref()
            .unwrap_or(DEFAULT_ADDR)
            .parse()
            .map_err(|e| ConfigError::Invalid(format!("addr: {e}")))?;
        let mut teams: Vec<Team> = Vec::new();
        let mut seen_tokens = std::collections::HashSet::new();
        for (i, entry) in file.teams.iter().enumerate() {
            let name = entry.name.trim();
            if name.is_empty()
                || !name
                    .chars()
                    .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_')
            {
                return Err(ConfigError::Invalid(format!(
                    "teams[{i}].name {:?}: use letters, digits, '-' and '_'",
                    entry.name
                )));
            }
            if teams.iter().any(|t| t.name == name) {
                return Err(ConfigError::Invalid(format!(
                    "teams[{i}].name {name:?} appears twice"
                )));
            }
            let tokens: Vec<&String> = entry.token.iter().chain(entry.tokens.iter()).collect();
            if tokens.is_empty() {
                return Err(ConfigError::Invalid(format!(
                    "team {name:?} has no token (set `token` or `tokens`)"
                )));
            }
            let mut token_hashes = Vec::new();
            for token in tokens {
                if token.trim().is_empty() {
                    return Err(ConfigError::Invalid(format!(
                        "team {name:?} has an empty token"
                    )));
                }
                let hash = *blake3::hash(token.as_bytes()).as_bytes();
                if !seen_tokens.insert(hash) {
                    return Err(ConfigError::Invalid(format!(
                        "team {name:?}: a token is used twice"
                    )));
                }
                token_hashes.push(hash);
            }
            teams.push(Team {
                name: name.to_string(),
                token_hashes,
            });
        }
        if file.open && !file.teams.is_empty() {
            return Err(ConfigError::Invalid(
                "open = true and [[teams]] exclude each other: an open service has no tokens"
                    .into(),
            ));
        }
        if file.teams.is_empty() && !file.open {
            return Err(ConfigError::Invalid(
                "no [[teams]]: a config file names at least one team and its token; run without \
                 --config, or set open = true, for open local mode"
                    .into(),
            ));
        }
        if file.limits.queue_capacity == 0 || file.limits.concurrent_bakes == 0 {
            return Err(ConfigError::Invalid(
                "limits.queue_capacity and limits.concurrent_bakes must be at least 1".into(),
            ));
        }
        Ok(ServiceConfig {
            addr,
            data: file.data.unwrap_or_else(|| PathBuf::from(DEFAULT_DATA)),
            limits: file.limits,
            teams,
            farm: file.farm,
        })
    }

    /// True when requests need no token.
    pub fn is_open(&self) -> bool {
        self.teams.is_empty()
    }
}

/// Refuses an open configuration on a non-loopback address.
pub fn check_bind(config: &ServiceConfig) -> Result<(), ConfigError> {
    if config.is_open() && !config.addr.ip().is_loopback() {
        return Err(ConfigError::OpenOnNonLoopback(config.addr));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `open = true` gives open mode with the file's limits, still on loopback only.
    #[test]
    fn an_open_file_keeps_its_limits_and_loopback() {
        let c = ServiceConfig::from_toml("open = true\n[limits]\nmax_texels = 3000").unwrap();
        assert!(c.is_open());
        assert_eq!(c.limits.max_texels, 3000);
        assert!(check_bind(&c).is_ok());
        let c = ServiceConfig::from_toml("open = true\naddr = \"0.0.0.0:9000\"").unwrap();
        assert!(check_bind(&c).is_err());
    }

    #[test]
    fn parses_teams_and_limits() {
        let c = ServiceConfig::from_toml(
            r#"
            addr = "0.0.0.0:9000"
            [limits]
            queue_capacity = 3
            [[teams]]
            name = "alpha"
            token = "a-secret"
            [[teams]]
            name = "beta"
            tokens = ["b1", "b2"]
            "#,
        )
        .unwrap();
        assert_eq!(c.addr.port(), 9000);
        assert_eq!(c.limits.queue_capacity, 3);
        assert_eq!(
            c.limits.concurrent_bakes,
            Limits::default().concurrent_bakes
        );
        assert_eq!(c.teams.len(), 2);
        assert_eq!(c.teams[1].token_hashes.len(), 2);
        assert!(check_bind(&c).is_ok());
    }

    #[test]
    fn refuses_bad_files() {
        for (text, needle) in [
            ("[[teams]]\nname = \"a b\"\ntoken = \"x\"", "teams[0].name"),
            ("[[teams]]\nname = \"a\"", "no token"),
            (
                "[[teams]]\nname = \"a\"\ntoken = \"x\"\n[[teams]]\nname = \"b\"\ntoken = \"x\"",
                "used twice",
            ),
            (
                "addr = \"nowhere\"\n[[teams]]\nname = \"a\"\ntoken = \"x\"",
                "addr",
            ),
            ("", "no [[teams]]"),
            (
                "open = true\n[[teams]]\nname = \"a\"\ntoken = \"x\"",
                "exclude each other",
            ),
            ("[limits]\nqueue_capasity = 3", "queue_capasity"),
        ] {
            let e = ServiceConfig::from_toml(text).unwrap_err().to_string();
            assert!(e.contains(needle), "{text:?}: {e}");
        }
    }

    #[test]
    fn open_mode_is_loopback_only() {
        let open = ServiceConfig::open_local("0.0.0.0:8080".parse().unwrap(), "d".into());
        assert!(matches!(
            check_bind(&open),
            Err(ConfigError::OpenOnNonLoopback(_))
        ));
        let local = ServiceConfig::open_local("127.0.0.1:0".parse().unwrap(), "d".into());
        assert!(check_bind(&local).is_ok());
        let v6 = ServiceConfig::open_local("[::1]:0".parse().unwrap(), "d".into());
        assert!(check_bind(&v6).is_ok());
    }
}
