//! Runs a netlist's testbench under Icarus Verilog (`iverilog` + `vvp`, Debian package
//! `iverilog`) on raw input values and reads back the raw outputs and overflow flags.
//! Used by `grid-gen eval --backend verilog` and by the tests.

use std::path::Path;
use std::process::Command;

use super::{run, RunError, Scratch};
use crate::back::verilog::{Netlist, MAX_STATES};
use crate::ir::Robot;

#[derive(Debug, thiserror::Error)]
pub enum SimError {
    #[error("Icarus Verilog is not installed (`iverilog` and `vvp` not found on PATH); install the Debian package `iverilog`")]
    NoSimulator,
    #[error("simulation scratch files: {0}")]
    Io(#[from] std::io::Error),
    #[error("`{step}` failed: {stderr}")]
    Failed { step: &'static str, stderr: String },
    #[error("the testbench wrote unexpected output: {0}")]
    Output(String),
}

/// The outputs of one simulated state: every non-zero output entry (raw, in
/// [`super::PortNames`] order) and the overflow flag.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SimResult {
    pub outputs: Vec<i128>,
    pub overflow: bool,
}

/// Whether `iverilog` can be run.
pub fn available() -> bool {
    Command::new("iverilog").arg("-V").output().map(|o| o.status.success()).unwrap_or(false)
}

fn sim(step: &'static str, cmd: &mut Command) -> Result<String, SimError> {
    run(cmd).map_err(|e| match e {
        RunError::NotFound(_) => SimError::NoSimulator,
        RunError::Io(e) => SimError::Io(e),
        RunError::Failed { stdout, stderr } => {
            SimError::Failed { step, stderr: format!("{stdout}{stderr}") }
        }
    })
}

/// Compiles the netlist and its testbench once, then simulates `ports` (one raw vector
/// per state, in port order), in batches of the testbench's capacity.
pub fn simulate(
    netlist: &Netlist,
    robot: &Robot,
    ports: &[Vec<i128>],
) -> Result<Vec<SimResult>, SimError> {
    let scratch = Scratch::new("sim")?;
    let (v, tb) = netlist.file_names();
    std::fs::write(scratch.path().join(&v), netlist.verilog(robot))?;
    std::fs::write(scratch.path().join(&tb), netlist.testbench())?;
    let image = scratch.path().join("sim.vvp");
    sim(
        "iverilog",
        Command::new("iverilog")
            .arg("-g2005")
            .arg("-o")
            .arg(&image)
            .arg("-s")
            .arg(format!("{}_tb", netlist.top))
            .arg(scratch.path().join(&v))
            .arg(scratch.path().join(&tb)),
    )?;
    let mut results = Vec::with_capacity(ports.len());
    for batch in ports.chunks(MAX_STATES) {
        results.extend(simulate_batch(netlist, scratch.path(), &image, batch)?);
    }
    Ok(results)
}

fn simulate_batch(
    netlist: &Netlist,
    dir: &Path,
    image: &Path,
    batch: &[Vec<i128>],
) -> Result<Vec<SimResult>, SimError> {
    let w = netlist.format.width;
    let mask = (1u128 << w) - 1;
    let mut hex = String::new();
    for state in batch {
        for &x in state {
            hex.push_str(&format!("{:x}\n", x as u128 & mask));
        }
    }
    let (inp, outp) = (dir.join("in.hex"), dir.join("out.txt"));
    std::fs::write(&inp, hex)?;
    let stdout = sim(
        "vvp",
        Command::new("vvp")
            .arg("-n")
            .arg(image)
            .arg(format!("+n={}", batch.len()))
            .arg(format!("+in={}", inp.display()))
            .arg(format!("+out={}", outp.display())),
    )?;
    if stdout.contains("timeout") || stdout.contains("usage") {
        return Err(SimError::Output(stdout));
    }
    let text = std::fs::read_to_string(&outp)?;
    let expected = netlist.names.outputs.len();
    // Formats have at most 120 bits: the value's sign bit shifted to the top of i128.
    let sign = |raw: u128| -> i128 { ((raw << (128 - w)) as i128) >> (128 - w) };
    let results: Vec<SimResult> = text
        .lines()
        .map(|line| {
            let fields: Vec<&str> = line.split_whitespace().collect();
            if fields.len() != expected + 1 {
                return Err(SimError::Output(format!(
                    "a line has {} fields, expected {}",
                    fields.len(),
                    expected + 1
                )));
            }
            let outputs = fields[..expected]
                .iter()
                .map(|f| {
                    u128::from_str_radix(f, 16).map(sign).map_err(|_| {
                        SimError::Output(format!(
                            "`{f}` is not a hex value (x or z in the netlist?)"
                        ))
                    })
                })
                .collect::<Result<Vec<i128>, _>>()?;
            Ok(SimResult { outputs, overflow: fields[expected] == "1" })
        })
        .collect::<Result<_, _>>()?;
    if results.len() != batch.len() {
        return Err(SimError::Output(format!("{} states in, {} out", batch.len(), results.len())));
    }
    Ok(results)
}
