//! The CLI's console: stdout that a reader closing the pipe does not break, errors as text
//! or JSON, the log set-up, and progress while the stages and photos run.
//!
//! **Closed stdout.** `cloudcontrol lidar catalogue tiles/ | head -1`: `head` closes the
//! pipe after its line, and the next write fails with `EPIPE` (Rust ignores `SIGPIPE`,
//! so the write returns the error, and `println!` would panic: exit status 101). Every
//! stdout write of the CLI goes through [`write_stdout`] ([`outln!`], [`out!`]): on a
//! broken pipe the rest of the command's stdout is dropped and the command carries on,
//! finishing its files (a `--out` file is written after the summary is printed) and
//! exiting with its own status, 0 when it succeeded. Restoring `SIGPIPE`'s default
//! instead would kill the process at the write: files it had yet to write would be
//! missing, and the shell would see 141, which `set -o pipefail` makes a failure of
//! `… | head`. Other stdout errors (a full disk under `> file`) end the command with
//! status 1. Writes to stderr ([`errln!`]) ignore errors: there is nowhere left to say so.

use indicatif::{ProgressBar, ProgressStyle};
use std::fmt;
use std::io::{IsTerminal, Write};
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Mutex;
use std::time::{Duration, Instant};

/// Prints a line to stdout through [`write_stdout`].
macro_rules! outln {
    () => {
        $crate::console::write_stdout(format_args!("\n"))
    };
    ($($arg:tt)*) => {
        $crate::console::write_stdout(format_args!("{}\n", format_args!($($arg)*)))
    };
}

/// Prints to stdout through [`write_stdout`], without a line end.
macro_rules! out {
    ($($arg:tt)*) => {
        $crate::console::write_stdout(format_args!($($arg)*))
    };
}

/// Prints a line to stderr, ignoring a closed or failing stderr.
macro_rules! errln {
    ($($arg:tt)*) => {
        $crate::console::write_stderr(format_args!("{}\n", format_args!($($arg)*)))
    };
}

static STDOUT_CLOSED: AtomicBool = AtomicBool::new(false);
static JSON: AtomicBool = AtomicBool::new(false);

/// Writes to stdout. A reader that closed the pipe (`EPIPE`) ends the command's stdout
/// only: this and later writes are dropped and the command carries on. Any other error
/// ends the command with [`crate::EXIT_FAILED`], saying so on stderr.
pub fn write_stdout(args: fmt::Arguments) {
    if STDOUT_CLOSED.load(Ordering::Relaxed) {
        return;
    }
    let mut o = std::io::stdout().lock();
    match o.write_fmt(args).and_then(|()| o.flush()) {
        Ok(()) => {}
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => {
            STDOUT_CLOSED.store(true, Ordering::Relaxed);
        }
        Err(e) => {
            write_stderr(format_args!("cloudcontrol: writing to stdout: {e}\n"));
            std::process::exit(crate::EXIT_FAILED.into());
        }
    }
}

/// Writes to stderr (through the progress bar when one is drawn, so that the line is not
/// drawn over), ignoring errors.
pub fn write_stderr(args: fmt::Arguments) {
    let text = args.to_string();
    if let Ok(p) = PROGRESS.lock() {
        if let Some(bar) = p.as_ref().and_then(|p| p.bar.as_ref()) {
            bar.suspend(|| {
                let _ = std::io::stderr().lock().write_all(text.as_bytes());
            });
            return;
        }
    }
    let _ = std::io::stderr().lock().write_all(text.as_bytes());
}

/// Whether `--json` was given: results and errors as JSON on stdout.
pub fn set_json(json: bool) {
    JSON.store(json, Ordering::Relaxed);
}

fn json() -> bool {
    JSON.load(Ordering::Relaxed)
}

/// A command's result: its report as JSON on stdout with `--json`, else `summary()` as one
/// line (nothing with `-q`).
pub fn report<T: serde::Serialize>(
    json: bool,
    quiet: bool,
    value: &T,
    summary: impl FnOnce() -> String,
) {
    if json {
        outln!(
            "{}",
            serde_json::to_string_pretty(value).expect("report serialises")
        );
    } else if !quiet {
        outln!("{}", summary());
    }
}

/// A failed command: the message on stderr (`cloudcontrol CMD: message`), and with
/// `--json` on stdout as `{"error": {"command", "message", "input", "exit_status"}}`,
/// `input` being the file the message names (or null); exits with `status`.
pub fn fail(command: &str, message: impl fmt::Display, status: u8) -> ExitCode {
    let message = message.to_string();
    if command.is_empty() {
        errln!("cloudcontrol: {message}");
    } else {
        errln!("cloudcontrol {command}: {message}");
    }
    if json() {
        let doc = serde_json::json!({
            "error": {
                "command": (!command.is_empty()).then_some(command),
                "message": message,
                "input": input_of(&message),
                "exit_status": status,
            }
        });
        outln!(
            "{}",
            serde_json::to_string_pretty(&doc).expect("error serialises")
        );
    }
    ExitCode::from(status)
}

/// The input an error message names: errors name it first (`path: what was wrong`,
/// `stage x: path: …`), so the first `: `-separated part that is an existing path or an
/// argument of the command line.
pub fn input_of(message: &str) -> Option<String> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    message
        .split(": ")
        .map(str::trim)
        .find(|part| {
            !part.is_empty()
                && !part.contains('\n')
                && (args.iter().any(|a| a == part) || std::path::Path::new(part).exists())
        })
        .map(str::to_string)
}

/// Logs on stderr: `--quiet` errors only, else warnings, `-v` info, `-vv` debug (or
/// `CLOUDCONTROL_LOG`, an env-filter directive). Colours only when stderr is a terminal:
/// a log file or pipe gets plain text. Besides, the library's progress events (target
/// `cloudcontrol::progress`) drive [`stage_progress`]'s display.
pub fn init_logging(quiet: bool, verbose: u8) {
    use tracing_subscriber::layer::SubscriberExt;
    use tracing_subscriber::util::SubscriberInitExt;
    use tracing_subscriber::Layer;
    let level = if quiet {
        "error"
    } else {
        match verbose {
            0 => "warn",
            1 => "info",
            2 => "debug",
            _ => "trace",
        }
    };
    let filter = tracing_subscriber::EnvFilter::try_from_env("CLOUDCONTROL_LOG")
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(level));
    let log = tracing_subscriber::fmt::layer()
        .with_writer(LogWriter)
        .with_ansi(std::io::stderr().is_terminal())
        .with_filter(filter);
    let progress = ProgressEvents.with_filter(tracing_subscriber::filter::filter_fn(|m| {
        m.target() == PROGRESS_TARGET
    }));
    let _ = tracing_subscriber::registry()
        .with(log)
        .with(progress)
        .try_init();
}

/// Log lines go through [`write_stderr`]: above the progress bar, never into it.
struct LogWriter;

impl<'a> tracing_subscriber::fmt::MakeWriter<'a> for LogWriter {
    type Writer = LogLine;
    fn make_writer(&'a self) -> LogLine {
        LogLine(Vec::new())
    }
}

/// One log event's text, written out whole when the formatter is done with it.
struct LogLine(Vec<u8>);

impl Write for LogLine {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.0.extend_from_slice(buf);
        Ok(buf.len())
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

impl Drop for LogLine {
    fn drop(&mut self) {
        if !self.0.is_empty() {
            write_stderr(format_args!("{}", String::from_utf8_lossy(&self.0)));
        }
    }
}

/// The target of the library's progress events: one per finished piece of work of a stage
/// (a photo's orientation, a scan's fiducials, a tile), with the fields `work` (what was
/// done), `item` (to what), `done` and `total` (of the stage's current batch).
const PROGRESS_TARGET: &str = "cloudcontrol::progress";

/// What is shown while a command runs: a spinner with the stage and the last piece of
/// work on a terminal; plain lines otherwise (a log file must show what a long run is
/// doing: a line per stage and per photo, at most one per 2 s in batches of over 100).
struct Progress {
    /// The spinner (terminal only).
    bar: Option<ProgressBar>,
    stage: String,
    last_line: Option<Instant>,
}

static PROGRESS: Mutex<Option<Progress>> = Mutex::new(None);

/// The display of a command's progress; cleared when dropped.
pub struct ProgressGuard(());

impl ProgressGuard {
    /// Starts showing progress on stderr (nothing when `hidden`: `--quiet`, `--json`).
    pub fn start(hidden: bool, stage: &str) -> Self {
        if hidden {
            return Self(());
        }
        let bar = std::io::stderr().is_terminal().then(|| {
            let b = ProgressBar::new_spinner();
            b.set_style(
                ProgressStyle::with_template("{spinner} [{elapsed_precise}] {msg}")
                    .unwrap_or_else(|_| ProgressStyle::default_spinner()),
            );
            b.enable_steady_tick(Duration::from_millis(120));
            b.set_message(stage.to_string());
            b
        });
        if let Ok(mut p) = PROGRESS.lock() {
            *p = Some(Progress {
                bar,
                stage: stage.to_string(),
                last_line: None,
            });
        }
        Self(())
    }
}

impl Drop for ProgressGuard {
    fn drop(&mut self) {
        if let Ok(mut p) = PROGRESS.lock() {
            if let Some(b) = p.take().and_then(|p| p.bar) {
                b.finish_and_clear();
            }
        }
    }
}

/// A stage started: the spinner's message, or a line (`[index/total] stage`).
pub fn stage(stage: &str) {
    if let Ok(mut guard) = PROGRESS.lock() {
        if let Some(p) = guard.as_mut() {
            p.stage = stage.to_string();
            p.last_line = None;
            match &p.bar {
                Some(b) => b.set_message(stage.to_string()),
                None => {
                    let _ = writeln!(std::io::stderr().lock(), "{stage}");
                }
            }
        }
    }
}

/// A line above the spinner, or a plain line without one (nothing while no progress is
/// shown).
pub fn line(text: &str) {
    if let Ok(guard) = PROGRESS.lock() {
        match guard.as_ref().map(|p| &p.bar) {
            Some(Some(b)) => b.println(text),
            Some(None) => {
                let _ = writeln!(std::io::stderr().lock(), "{text}");
            }
            None => {}
        }
    }
}

/// A progress event of the library: the spinner's message, or a plain line.
fn on_progress(work: &str, item: &str, done: u64, total: u64) {
    let Ok(mut guard) = PROGRESS.lock() else {
        return;
    };
    let Some(p) = guard.as_mut() else {
        return;
    };
    let what = format!("{work} {done}/{total} {item}");
    match &p.bar {
        Some(b) => b.set_message(format!("{} · {what}", p.stage)),
        None => {
            // A line per item; a batch of many (LiDAR or orthophoto tiles, a large
            // epoch) at most one line per 2 s, and its last.
            let due = total <= 100
                || p.last_line
                    .is_none_or(|t| t.elapsed() >= Duration::from_secs(2));
            if due || done == total {
                p.last_line = Some(Instant::now());
                let _ = writeln!(std::io::stderr().lock(), "  {}: {what}", p.stage);
            }
        }
    }
}

/// The layer that hands the library's progress events to [`on_progress`].
struct ProgressEvents;

impl<S: tracing::Subscriber> tracing_subscriber::Layer<S> for ProgressEvents {
    fn on_event(&self, event: &tracing::Event<'_>, _: tracing_subscriber::layer::Context<'_, S>) {
        let mut f = ProgressFields::default();
        event.record(&mut f);
        on_progress(&f.work, &f.item, f.done, f.total);
    }
}

#[derive(Default)]
struct ProgressFields {
    work: String,
    item: String,
    done: u64,
    total: u64,
}

impl tracing::field::Visit for ProgressFields {
    fn record_u64(&mut self, field: &tracing::field::Field, value: u64) {
        match field.name() {
            "done" => self.done = value,
            "total" => self.total = value,
            _ => {}
        }
    }
    fn record_i64(&mut self, field: &tracing::field::Field, value: i64) {
        self.record_u64(field, value.max(0) as u64)
    }
    fn record_str(&mut self, field: &tracing::field::Field, value: &str) {
        match field.name() {
            "work" => self.work = value.to_string(),
            "item" => self.item = value.to_string(),
            _ => {}
        }
    }
    fn record_debug(&mut self, field: &tracing::field::Field, value: &dyn fmt::Debug) {
        match field.name() {
            "work" => self.work = format!("{value:?}").trim_matches('"').to_string(),
            "item" => self.item = format!("{value:?}").trim_matches('"').to_string(),
            _ => {}
        }
    }
}
