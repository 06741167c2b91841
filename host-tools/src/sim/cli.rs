//! `scip2can sim`: the command-line front of the simulator.

use std::net::TcpListener;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

use anyhow::Context;

use super::options::SimOptions;
use super::transport::{serve_pty, serve_stdio, serve_tcp, Clock};

/// Flags of `scip2can sim`.
#[derive(Debug, Clone, clap::Args)]
pub struct SimArgs {
    /// What the sensor is and sees.
    #[command(flatten)]
    pub options: SimOptions,
    /// Serve TCP on this address (the default transport, like Ethernet models).
    #[arg(long, default_value = "127.0.0.1:10940")]
    pub tcp: String,
    /// Serve a pseudo-terminal instead; its path is printed on standard output.
    #[arg(long, conflicts_with = "stdio")]
    pub pty: bool,
    /// Serve standard input and output instead.
    #[arg(long)]
    pub stdio: bool,
    /// On a pty, write as fast as possible instead of at the sensor's bit rate (through
    /// its bounded transmit buffer, skipping the scans the line cannot carry).
    #[arg(long)]
    pub no_pace: bool,
}

/// Runs the simulator until it is killed (or, on stdio, until input ends).
pub fn run(args: SimArgs) -> anyhow::Result<()> {
    let mut sensor = args.options.build()?;
    let clock = Clock::new(args.options.speed);
    let stop = Arc::new(AtomicBool::new(false));
    let mut log = |line: &str| eprintln!("scip2can sim: {line}");
    let name = sensor.model().kind.name();
    if args.stdio {
        serve_stdio(&mut sensor, &clock, &mut log)?;
    } else if args.pty {
        let mut ready = |path: &str| {
            println!("{path}");
            eprintln!("scip2can sim: {name} on pseudo-terminal {path}");
        };
        serve_pty(
            &mut sensor,
            &clock,
            &stop,
            !args.no_pace,
            &mut ready,
            &mut log,
        )?;
    } else {
        let listener =
            TcpListener::bind(&args.tcp).with_context(|| format!("binding {}", args.tcp))?;
        let addr = listener.local_addr()?;
        println!("tcp://{addr}");
        eprintln!("scip2can sim: {name} on tcp://{addr}");
        serve_tcp(listener, &mut sensor, &clock, &stop, &mut log)?;
    }
    Ok(())
}
