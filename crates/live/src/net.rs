//! Opening a Zenoh session: peer mode, the endpoints to listen on and connect to, multicast
//! scouting on or off, and the transport's bound on a reassembled message.

use zenoh::Wait;

use crate::LiveError;

/// Largest message the transport reassembles from fragments: 64 MiB (Zenoh's default is
/// 1 GiB). Every kfuse message is far smaller ([`crate::keys::MAX_IMAGE_BYTES`] is the
/// largest accepted); a peer sending more is cut off by Zenoh before any allocation of that
/// size, and the receiver checks each topic's own limit before decoding.
pub const MAX_TRANSPORT_MESSAGE_BYTES: usize = 64 << 20;

/// Where a session listens and what it connects to.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Endpoints {
    /// Endpoints to listen on (`tcp/0.0.0.0:7447`, `tcp/127.0.0.1:17000`); empty: Zenoh's
    /// default for a peer (a free TCP port on every interface).
    pub listen: Vec<String>,
    /// Endpoints of other peers or routers to connect to (`tcp/192.168.1.20:7447`).
    pub connect: Vec<String>,
    /// Find peers by UDP multicast scouting (Zenoh's default on a LAN). Off: only
    /// [`Endpoints::connect`] (and gossip through them).
    pub multicast: bool,
}

fn json_list(items: &[String]) -> Result<String, LiveError> {
    serde_json::to_string(items).map_err(|e| LiveError::Config(e.to_string()))
}

/// The Zenoh configuration of `e` (peer mode).
pub fn config(e: &Endpoints) -> Result<zenoh::Config, LiveError> {
    let mut c = zenoh::Config::default();
    let set = |c: &mut zenoh::Config, key: &str, value: String| {
        c.insert_json5(key, &value)
            .map_err(|err| LiveError::Config(format!("{key}={value}: {err}")))
    };
    set(&mut c, "mode", "\"peer\"".into())?;
    if !e.listen.is_empty() {
        set(&mut c, "listen/endpoints", json_list(&e.listen)?)?;
    }
    if !e.connect.is_empty() {
        set(&mut c, "connect/endpoints", json_list(&e.connect)?)?;
    }
    set(&mut c, "scouting/multicast/enabled", e.multicast.to_string())?;
    set(&mut c, "transport/link/rx/max_message_size", MAX_TRANSPORT_MESSAGE_BYTES.to_string())?;
    Ok(c)
}

/// Opens a session. Error: an endpoint Zenoh does not accept, or one it cannot listen on (the
/// port is taken).
pub fn open(e: &Endpoints) -> Result<zenoh::Session, LiveError> {
    let c = config(e)?;
    zenoh::open(c).wait().map_err(|err| {
        LiveError::Zenoh(format!(
            "opening a Zenoh session (listen {:?}, connect {:?}): {err}",
            e.listen, e.connect
        ))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn endpoints_reach_the_config() {
        let e = Endpoints {
            listen: vec!["tcp/127.0.0.1:7999".into()],
            connect: vec!["tcp/127.0.0.1:7998".into()],
            multicast: false,
        };
        let c = config(&e).unwrap();
        let text = format!("{c}");
        assert!(text.contains("tcp/127.0.0.1:7999"), "{text}");
        assert!(text.contains("tcp/127.0.0.1:7998"), "{text}");
    }

    #[test]
    fn a_bad_endpoint_is_an_error() {
        let e = Endpoints { listen: vec!["nonsense".into()], ..Endpoints::default() };
        assert!(config(&e).is_err() || open(&e).is_err());
    }
}
