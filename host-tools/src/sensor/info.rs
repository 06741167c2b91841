//! `scip2can info`: VV, PP and II of a sensor, pretty.

use std::io::Write;

use scip::{Command, Request, Status};
use serde_json::{Map, Value};

use super::client::{Client, Response};

/// The three information responses.
#[derive(Debug, Clone, PartialEq)]
pub struct Info {
    /// VV fields.
    pub version: Vec<(String, String)>,
    /// PP fields.
    pub parameters: Vec<(String, String)>,
    /// II fields.
    pub status: Vec<(String, String)>,
}

fn ask(client: &mut Client, cmd: Command) -> anyhow::Result<Response> {
    let r = client.command(&Request::new(cmd))?;
    if !r.is_intact() {
        anyhow::bail!("damaged answer to {}: {:?}", r.echo_str(), r.errors);
    }
    if r.status != Some(Status::OK) {
        anyhow::bail!("{} answered status {}", r.echo_str(), r.status_str());
    }
    Ok(r)
}

/// Asks VV, PP, II.
pub fn query(client: &mut Client) -> anyhow::Result<Info> {
    Ok(Info {
        version: ask(client, Command::Version)?.fields,
        parameters: ask(client, Command::Parameters)?.fields,
        status: ask(client, Command::Info)?.fields,
    })
}

/// Writes the info as aligned text, one section per command.
pub fn write_pretty(info: &Info, out: &mut dyn Write) -> std::io::Result<()> {
    for (title, fields) in [
        ("Version (VV)", &info.version),
        ("Parameters (PP)", &info.parameters),
        ("Status (II)", &info.status),
    ] {
        writeln!(out, "{title}")?;
        for (name, value) in fields {
            writeln!(out, "  {name:<5} {value}")?;
        }
    }
    Ok(())
}

/// The info as one JSON object `{"VV": {...}, "PP": {...}, "II": {...}}`.
pub fn to_json(info: &Info) -> Value {
    let obj = |f: &Vec<(String, String)>| {
        Value::Object(
            f.iter()
                .map(|(n, v)| (n.clone(), Value::String(v.clone())))
                .collect::<Map<_, _>>(),
        )
    };
    serde_json::json!({"VV": obj(&info.version), "PP": obj(&info.parameters), "II": obj(&info.status)})
}
