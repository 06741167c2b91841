//! The MCAP file of `decode --mcap`: what a ROS 2 user can `ros2 bag play` and
//! Foxglove opens.
//!
//! Per bridge node, the scans on one or two channels ([`McapSchema`], `--mcap-schema`):
//! - `ros2` (the default): the topic template (`--topic`, default
//!   `/scip2can/node{node}/scan`) with `sensor_msgs/msg/LaserScan` (schema encoding
//!   `ros2msg`, message encoding `cdr`), profile `ros2`: a file `ros2 bag play` and the
//!   rosbags library read, and Foxglove shows;
//! - `foxglove`: that topic with `foxglove.LaserScan` (`protobuf`) instead;
//! - `both`: both, the Foxglove channel on the topic plus `/foxglove`. ROS 2 tools
//!   that take only ROS 2 schemas (the rosbags library) cannot read such a file.
//!
//! and one `/diagnostics` channel (`--diagnostics-topic`) of
//! `diagnostic_msgs/msg/DiagnosticArray` with one status per status frame of any
//! bridge (see [`super::ros2::diagnostic`]). Control frames and answers are not
//! written.
//!
//! Every message's log and publish time is the log time of the frame that completed it
//! (when it was received); a scan's header stamp is the scan's own time
//! ([`super::scan_stamp_ns`]); a diagnostic's stamp is its log time (status frames
//! carry no time). Chunks are not compressed. The file is finished (summary and
//! footer) at the end of the input, and also when decoding stops on an error, so it
//! always holds what was written.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

use anyhow::{anyhow, bail, Context};
use mcap::records::MessageHeader;
use mcap::{WriteOptions, Writer};

use super::{expand, foxglove, laser_scan, ros2, NodeInfo, Skip};
use crate::decode::Item;

/// Topic and frame options of the MCAP output.
#[derive(Debug, Clone, clap::Args)]
pub struct McapArgs {
    /// Write the scans to this MCAP file (ROS 2 LaserScan + Foxglove LaserScan per
    /// bridge node, status frames as diagnostics).
    #[arg(long, value_name = "FILE")]
    pub mcap: Option<PathBuf>,
    /// Topic of each bridge's ROS 2 LaserScan channel; `{node}` is the node number (the
    /// Foxglove channel is this topic plus `/foxglove`). Without `{node}`, only one
    /// bridge may appear in the log.
    #[arg(long, default_value = "/scip2can/node{node}/scan", requires = "mcap")]
    pub topic: String,
    /// Coordinate frame of the scans; `{node}` is the node number.
    #[arg(long, default_value = "laser{node}", requires = "mcap")]
    pub frame_id: String,
    /// Topic of the diagnostics channel (status frames).
    #[arg(long, default_value = "/diagnostics", requires = "mcap")]
    pub diagnostics_topic: String,
    /// The scans' message type: ros2 (sensor_msgs/msg/LaserScan), foxglove
    /// (foxglove.LaserScan) or both (the Foxglove channel on TOPIC/foxglove).
    #[arg(long, value_enum, default_value_t = McapSchema::Ros2, requires = "mcap")]
    pub mcap_schema: McapSchema,
    /// The scans' range_min in metres (default: the sensor's DMIN from the bridge's
    /// status page 4, else the smallest range the encoding expresses).
    #[arg(long, value_name = "M", requires = "mcap")]
    pub range_min: Option<f32>,
    /// The scans' range_max in metres (default: the sensor's DMAX from status page 4,
    /// else the largest range the encoding expresses).
    #[arg(long, value_name = "M", requires = "mcap")]
    pub range_max: Option<f32>,
}

/// Which message types carry the scans.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum McapSchema {
    /// `sensor_msgs/msg/LaserScan` (CDR), profile `ros2`.
    Ros2,
    /// `foxglove.LaserScan` (protobuf).
    Foxglove,
    /// Both; the Foxglove channel on the topic plus `/foxglove`.
    Both,
}

impl McapSchema {
    fn ros2(self) -> bool {
        self != McapSchema::Foxglove
    }

    fn foxglove(self) -> bool {
        self != McapSchema::Ros2
    }
}

/// Schema slots.
const LASER_SCAN: usize = 0;
const FOXGLOVE_SCAN: usize = 1;
const DIAGNOSTICS: usize = 2;

/// The channels of one bridge.
#[derive(Debug, Clone, Copy)]
struct NodeChannels {
    ros2: Option<u16>,
    foxglove: Option<u16>,
}

/// What went into the file.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct McapCounts {
    /// Scans written (with `both`, each on two channels).
    pub scans: u64,
    /// Scans left out: geometry unknown (`ares` 0).
    pub geometry_unknown: u64,
    /// Scans left out: CRC mismatch, corrupt or aborted.
    pub damaged: u64,
    /// Diagnostics written.
    pub diagnostics: u64,
}

/// An MCAP file being written.
pub struct McapSink {
    writer: Writer<BufWriter<File>>,
    path: PathBuf,
    topic: String,
    frame_id: String,
    diagnostics_topic: String,
    kind: McapSchema,
    /// `--range-min`, `--range-max`.
    range_limits: (Option<f32>, Option<f32>),
    schemas: [Option<u16>; 3],
    diagnostics: Option<u16>,
    channels: BTreeMap<u8, NodeChannels>,
    infos: BTreeMap<u8, NodeInfo>,
    sequence: u32,
    counts: McapCounts,
    warned_geometry: bool,
}

impl std::fmt::Debug for McapSink {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("McapSink")
            .field("path", &self.path)
            .field("counts", &self.counts)
            .finish_non_exhaustive()
    }
}

/// Creates `path`, with an error that says what is wrong with it.
fn create(path: &Path) -> anyhow::Result<File> {
    let shown = path.display();
    if path.is_dir() {
        bail!("--mcap {shown}: is a directory; give a file name");
    }
    let parent = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    if parent.exists() && !parent.is_dir() {
        bail!("--mcap {shown}: {} is not a directory", parent.display());
    }
    if !parent.is_dir() {
        bail!(
            "--mcap {shown}: the directory {} does not exist",
            parent.display()
        );
    }
    File::create(path).with_context(|| format!("--mcap {shown}: cannot create the file"))
}

impl McapSink {
    /// Creates the file (before any input is read, so a bad path fails at once).
    pub fn create(
        path: &Path,
        topic: &str,
        frame_id: &str,
        diagnostics_topic: &str,
        schema: McapSchema,
    ) -> anyhow::Result<Self> {
        let file = create(path)?;
        let writer = WriteOptions::new()
            .profile(if schema == McapSchema::Foxglove {
                ""
            } else {
                "ros2"
            })
            .compression(None)
            .library(concat!("scip2can ", env!("CARGO_PKG_VERSION")))
            .create(BufWriter::new(file))
            .with_context(|| format!("--mcap {}: writing the header", path.display()))?;
        Ok(Self {
            writer,
            path: path.to_owned(),
            topic: topic.to_owned(),
            frame_id: frame_id.to_owned(),
            diagnostics_topic: diagnostics_topic.to_owned(),
            kind: schema,
            range_limits: (None, None),
            schemas: [None; 3],
            diagnostics: None,
            channels: BTreeMap::new(),
            infos: BTreeMap::new(),
            sequence: 0,
            counts: McapCounts::default(),
            warned_geometry: false,
        })
    }

    /// Creates the sink of `args`, `None` without `--mcap`.
    pub fn from_args(args: &McapArgs) -> anyhow::Result<Option<Self>> {
        args.mcap
            .as_deref()
            .map(|p| {
                let mut sink = Self::create(
                    p,
                    &args.topic,
                    &args.frame_id,
                    &args.diagnostics_topic,
                    args.mcap_schema,
                )?;
                sink.set_range_limits(args.range_min, args.range_max);
                Ok(sink)
            })
            .transpose()
    }

    /// Range limits (m) that replace what status frames and the encoding tell.
    pub fn set_range_limits(&mut self, min: Option<f32>, max: Option<f32>) {
        self.range_limits = (min, max);
    }

    fn err(&self, e: mcap::McapError) -> anyhow::Error {
        anyhow!("--mcap {}: {e}", self.path.display())
    }

    /// The id of a schema, added on first use (a file holds only the schemas it uses).
    fn schema(&mut self, which: usize) -> anyhow::Result<u16> {
        if let Some(id) = self.schemas[which] {
            return Ok(id);
        }
        let (name, encoding, data) = match which {
            LASER_SCAN => (
                ros2::LASER_SCAN.to_owned(),
                "ros2msg".to_owned(),
                ros2::laser_scan_schema().into_bytes(),
            ),
            FOXGLOVE_SCAN => {
                let fox = foxglove::laser_scan_schema();
                (fox.name, fox.encoding, fox.data.into_owned())
            }
            _ => (
                ros2::DIAGNOSTIC_ARRAY.to_owned(),
                "ros2msg".to_owned(),
                ros2::diagnostic_array_schema().into_bytes(),
            ),
        };
        let id = self.writer.add_schema(&name, &encoding, &data);
        let id = id.map_err(|e| self.err(e))?;
        self.schemas[which] = Some(id);
        Ok(id)
    }

    fn node_channels(&mut self, node: u8) -> anyhow::Result<NodeChannels> {
        if let Some(c) = self.channels.get(&node) {
            return Ok(*c);
        }
        if !self.topic.contains("{node}") {
            if let Some(first) = self.channels.keys().next() {
                bail!(
                    "--topic {:?} has no {{node}} and the log has more than one bridge \
                     (nodes {first} and {node}); put {{node}} in the topic",
                    self.topic
                );
            }
        }
        let topic = expand(&self.topic, node);
        let none = BTreeMap::new();
        let fox_topic = match self.kind {
            McapSchema::Both => format!("{topic}/foxglove"),
            _ => topic.clone(),
        };
        let mut c = NodeChannels {
            ros2: None,
            foxglove: None,
        };
        if self.kind.ros2() {
            let ros2_schema = self.schema(LASER_SCAN)?;
            let id = self.writer.add_channel(ros2_schema, &topic, "cdr", &none);
            c.ros2 = Some(id.map_err(|e| self.err(e))?);
        }
        if self.kind.foxglove() {
            let fox_schema = self.schema(FOXGLOVE_SCAN)?;
            let id = self
                .writer
                .add_channel(fox_schema, &fox_topic, "protobuf", &none);
            c.foxglove = Some(id.map_err(|e| self.err(e))?);
        }
        self.channels.insert(node, c);
        Ok(c)
    }

    fn write(&mut self, channel_id: u16, time_us: u64, data: &[u8]) -> anyhow::Result<()> {
        let t = time_us.saturating_mul(1000);
        let header = MessageHeader {
            channel_id,
            sequence: self.sequence,
            log_time: t,
            publish_time: t,
        };
        self.sequence = self.sequence.wrapping_add(1);
        self.writer
            .write_to_known_channel(&header, data)
            .map_err(|e| self.err(e))
    }

    /// Writes what `item` holds: a scan on its bridge's channels, a status frame as a
    /// diagnostic (and what it tells about the sensor is kept for later scans).
    pub fn push(&mut self, item: &Item) -> anyhow::Result<()> {
        match item {
            Item::Scan(s) => {
                let info = self.infos.get(&s.node).copied().unwrap_or_default();
                let frame = expand(&self.frame_id, s.node);
                match laser_scan(s, &info, &frame) {
                    Ok(mut scan) => {
                        scan.range_min = self.range_limits.0.unwrap_or(scan.range_min);
                        scan.range_max = self.range_limits.1.unwrap_or(scan.range_max);
                        let c = self.node_channels(s.node)?;
                        if let Some(id) = c.ros2 {
                            self.write(id, s.time_us, &ros2::laser_scan_cdr(&scan))?;
                        }
                        if let Some(id) = c.foxglove {
                            self.write(id, s.time_us, &foxglove::laser_scan_bytes(&scan))?;
                        }
                        self.counts.scans += 1;
                    }
                    Err(Skip::GeometryUnknown) => {
                        if !self.warned_geometry {
                            eprintln!(
                                "warning: node {} sends scans without geometry (ares 0): \
                                 they have no angles and are left out of the MCAP file",
                                s.node
                            );
                            self.warned_geometry = true;
                        }
                        self.counts.geometry_unknown += 1;
                    }
                    Err(Skip::NotPublishable(_)) => self.counts.damaged += 1,
                }
            }
            Item::Status {
                node,
                time_us,
                status,
            } => {
                self.infos.entry(*node).or_default().update(status);
                let channel = match self.diagnostics {
                    Some(c) => c,
                    None => {
                        let schema = self.schema(DIAGNOSTICS)?;
                        let topic = self.diagnostics_topic.clone();
                        let c = self
                            .writer
                            .add_channel(schema, &topic, "cdr", &BTreeMap::new())
                            .map_err(|e| self.err(e))?;
                        self.diagnostics = Some(c);
                        c
                    }
                };
                let d = ros2::diagnostic(*node, status);
                let bytes = ros2::diagnostic_array_cdr(time_us.saturating_mul(1000), &d);
                self.write(channel, *time_us, &bytes)?;
                self.counts.diagnostics += 1;
            }
            Item::Answer { .. } | Item::Control { .. } => {}
        }
        Ok(())
    }

    /// Writes the summary and closes the file.
    pub fn finish(mut self) -> anyhow::Result<McapCounts> {
        self.writer.finish().map_err(|e| self.err(e))?;
        Ok(self.counts)
    }

    /// What was written so far.
    pub fn counts(&self) -> McapCounts {
        self.counts
    }
}
