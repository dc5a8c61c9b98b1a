//! `bifirst bench`: every kernel, its CPU twin and, on a GPU adapter, the kernel in f64 and f32.

use anyhow::Result;
use bifirst::backend::BackendChoice;
use bifirst::bench::{bench_devices, run_bench, BenchOptions};
use std::process::ExitCode;
use std::time::Instant;

pub(crate) fn bench_command(options: BenchOptions, backend: BackendChoice, adapter: Option<String>, json: bool) -> Result<ExitCode> {
    bifirst::bench::check_filters(&options).map_err(anyhow::Error::msg)?;
    let devices = match backend {
        BackendChoice::Cpu => Vec::new(),
        BackendChoice::Gpu => bench_devices(adapter.as_deref())?,
        BackendChoice::Auto => bench_devices(adapter.as_deref()).unwrap_or_else(|e| {
            eprintln!("no GPU columns: {e}");
            Vec::new()
        }),
    };
    if !json {
        for d in &devices {
            eprintln!("device: {} in {}", d.adapter.line(), d.precision.name());
        }
        println!("{}", bifirst::bench::table_header());
    }
    let started = Instant::now();
    let progress = |case: &str| eprintln!("[{:6.1} s] {case}", started.elapsed().as_secs_f64());
    run_bench(
        &options,
        &devices,
        |row| {
            if json {
                println!("{}", serde_json::to_string(&row).expect("serializes"));
            } else {
                println!("{}", row.line());
            }
        },
        progress,
    )?;
    Ok(ExitCode::SUCCESS)
}
