//! `cloudcontrol convert IN OUT`: block format conversion (COLMAP folder ↔ BlocksExchange XML).

use cloudcontrol::formats::convert::{read_block, write_block, BlockFormat, ConvertOptions};
use std::path::PathBuf;
use std::process::ExitCode;

/// Convert a block between COLMAP (folder) and BlocksExchange (.xml).
///
/// Example: cloudcontrol convert sparse/0 block.xml
#[derive(clap::Args)]
pub struct Args {
    /// Input: a COLMAP model folder or a BlocksExchange .xml.
    input: PathBuf,
    /// Output: a folder (COLMAP) or a .xml (BlocksExchange).
    output: PathBuf,
    /// Input format when the path does not tell (colmap | bx).
    #[arg(long)]
    from: Option<String>,
    /// Output format when the path does not tell (colmap | bx).
    #[arg(long)]
    to: Option<String>,
    /// COLMAP output as text instead of binary.
    #[arg(long)]
    text: bool,
    /// COLMAP output in the legacy 3-file layout (no rigs/frames).
    #[arg(long)]
    legacy: bool,
}

fn format(s: &Option<String>) -> Result<Option<BlockFormat>, String> {
    s.as_deref()
        .map(|f| BlockFormat::parse(f).ok_or_else(|| format!("unknown format {f:?} (colmap | bx)")))
        .transpose()
}

pub fn run(a: Args, json: bool, quiet: bool) -> ExitCode {
    let result = (|| -> Result<_, String> {
        let block = read_block(&a.input, format(&a.from)?).map_err(|e| e.to_string())?;
        let opts = ConvertOptions {
            text: a.text,
            legacy: a.legacy,
        };
        write_block(&a.output, &block, format(&a.to)?, &opts).map_err(|e| e.to_string())?;
        Ok(block)
    })();
    match result {
        Ok(b) => {
            if json {
                outln!(
                    "{}",
                    serde_json::json!({
                        "input": a.input, "output": a.output, "cameras": b.cameras.len(),
                        "photos": b.photos.len(), "points": b.points.len(),
                        "observations": b.num_observations(), "crs": b.crs,
                    })
                );
            } else if !quiet {
                outln!(
                    "{} → {}: {} cameras, {} photos, {} points, {} observations",
                    a.input.display(),
                    a.output.display(),
                    b.cameras.len(),
                    b.photos.len(),
                    b.points.len(),
                    b.num_observations()
                );
            }
            ExitCode::SUCCESS
        }
        Err(e) => crate::console::fail("convert", e, crate::EXIT_FAILED),
    }
}
