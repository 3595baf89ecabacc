//! Which requests the server answers at all. The page's header ([`super::PAGE_HEADER`]) stops
//! other sites from sending changes, but not DNS rebinding: a site whose name the attacker
//! re-points at 127.0.0.1 is, to the browser, the page's own origin. So the server answers only
//! to the names it is known by, an IP address (what a rebinding attack cannot use, its origin
//! being the name) or `localhost` or a name given with `--allow-host`, and refuses changes whose
//! `Origin` is another site.

use axum::extract::{Request, State};
use axum::http::{HeaderMap, Method, StatusCode, header};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use std::net::IpAddr;
use std::sync::Arc;

/// The names the server answers to beyond IP addresses and `localhost`.
#[derive(Clone, Debug, Default)]
pub struct Hosts {
    /// Lower-case host names, without ports.
    pub names: Vec<String>,
}

/// The host part of a `Host` header value or an origin's authority (`name`, `name:port`,
/// `[v6]:port`), lower-cased; `None` when malformed.
pub fn host_of(authority: &str) -> Option<String> {
    let a = authority.trim();
    let host = if let Some(rest) = a.strip_prefix('[') {
        let (inside, after) = rest.split_once(']')?;
        if !(after.is_empty() || after.strip_prefix(':').is_some_and(|p| p.parse::<u16>().is_ok())) {
            return None;
        }
        inside.parse::<std::net::Ipv6Addr>().ok()?;
        inside
    } else {
        match a.rsplit_once(':') {
            Some((h, p)) if p.parse::<u16>().is_ok() => h,
            Some(_) => return None,
            None => a,
        }
    };
    let ok = !host.is_empty() && host.chars().all(|c| c.is_ascii_alphanumeric() || ".-_:".contains(c));
    ok.then(|| host.to_ascii_lowercase())
}

impl Hosts {
    /// Whether a request naming `host` (from its `Host` header) is for this server.
    pub fn allows(&self, host: &str) -> bool {
        host.parse::<IpAddr>().is_ok() || host == "localhost" || self.names.iter().any(|n| n == host)
    }

    /// `None` when the request may go on, else the refusal.
    pub fn check(&self, method: &Method, headers: &HeaderMap) -> Option<(StatusCode, String)> {
        let host_value = headers.get(header::HOST).and_then(|v| v.to_str().ok());
        let Some(host) = host_value.and_then(host_of) else {
            return Some((StatusCode::BAD_REQUEST, "the request has no valid Host header".into()));
        };
        if !self.allows(&host) {
            return Some((
                StatusCode::MISDIRECTED_REQUEST,
                format!(
                    "this server does not answer to the name “{}” (start it with --allow-host NAME to allow one)",
                    super::upload::display_name(&host)
                ),
            ));
        }
        let changes = !matches!(*method, Method::GET | Method::HEAD | Method::OPTIONS);
        if changes && let Some(origin) = headers.get(header::ORIGIN) {
            // Same origin: the scheme's authority must be the Host header's, port included.
            let same = origin
                .to_str()
                .ok()
                .and_then(|o| o.split_once("://"))
                .is_some_and(|(_, authority)| Some(authority.trim_end_matches('/')) == host_value.map(str::trim));
            if !same {
                return Some((
                    StatusCode::FORBIDDEN,
                    "changes are accepted from this server's own page only".into(),
                ));
            }
        }
        None
    }
}

/// The middleware: [`Hosts::check`] on every request.
pub async fn guard(State(hosts): State<Arc<Hosts>>, req: Request, next: Next) -> Response {
    match hosts.check(req.method(), req.headers()) {
        None => next.run(req).await,
        Some((status, message)) => super::error(status, message).into_response(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use axum::http::HeaderValue;

    fn headers(host: Option<&str>, origin: Option<&str>) -> HeaderMap {
        let mut h = HeaderMap::new();
        if let Some(v) = host {
            h.insert(header::HOST, HeaderValue::from_str(v).unwrap());
        }
        if let Some(v) = origin {
            h.insert(header::ORIGIN, HeaderValue::from_str(v).unwrap());
        }
        h
    }

    #[test]
    fn hosts_are_parsed_with_and_without_ports() {
        for (value, want) in [
            ("127.0.0.1:8080", Some("127.0.0.1")),
            ("LOCALHOST:1", Some("localhost")),
            ("localhost", Some("localhost")),
            ("[::1]:8080", Some("::1")),
            ("[::1]", Some("::1")),
            ("evil.example:18080", Some("evil.example")),
            ("a:b", None),
            ("[::1", None),
            ("[zz]:80", None),
            ("", None),
            ("a b", None),
            ("x:99999", None),
        ] {
            assert_eq!(host_of(value).as_deref(), want, "{value:?}");
        }
    }

    #[test]
    fn only_addresses_localhost_and_allowed_names_are_answered() {
        let h = Hosts {
            names: vec!["studio.lan".into()],
        };
        for ok in [
            "127.0.0.1:8080",
            "localhost:8080",
            "[::1]:80",
            "10.1.2.3",
            "studio.lan:8080",
        ] {
            assert_eq!(h.check(&Method::GET, &headers(Some(ok), None)), None, "{ok}");
        }
        for bad in ["evil.example:18080", "localhost.evil.example", "studio.lan.evil"] {
            let r = h.check(&Method::GET, &headers(Some(bad), None)).unwrap();
            assert_eq!(r.0, StatusCode::MISDIRECTED_REQUEST, "{bad}");
            assert!(r.1.contains("--allow-host"), "{}", r.1);
        }
        assert_eq!(
            h.check(&Method::GET, &headers(None, None)).unwrap().0,
            StatusCode::BAD_REQUEST
        );
    }

    #[test]
    fn changes_from_another_origin_are_refused() {
        let h = Hosts::default();
        let host = Some("127.0.0.1:8080");
        // The page's own origin, or no Origin at all (curl, scripts): accepted.
        assert_eq!(
            h.check(&Method::POST, &headers(host, Some("http://127.0.0.1:8080"))),
            None
        );
        assert_eq!(h.check(&Method::POST, &headers(host, None)), None);
        // Another site, another port, a null origin: refused; a GET from anywhere is not a change.
        for origin in [
            "http://evil.example",
            "http://127.0.0.1:9999",
            "null",
            "http://localhost:8080",
        ] {
            let r = h.check(&Method::POST, &headers(host, Some(origin))).unwrap();
            assert_eq!(r.0, StatusCode::FORBIDDEN, "{origin}");
        }
        assert_eq!(h.check(&Method::GET, &headers(host, Some("http://evil.example"))), None);
    }
}
