//! pinrt-capi's integration tests, one binary (one link of the crate and its dependencies).
//!
//! Without libtest's harness: this binary is also the isolated OpenVDB reader that pinbake
//! starts as a child process (`__vdb-worker`, for the C example's smoke), which a libtest
//! `main` cannot answer. `main` serves that, and otherwise runs the tests below one after
//! another with the part of libtest's command line that `cargo test` users reach for: name
//! filters, `--exact`, `--skip NAME` and `--list`.

mod common;

mod c_example;
mod c_hostile;
mod spirv_consumer;

use std::ffi::OsString;
use std::panic::catch_unwind;
use std::process::ExitCode;

const TESTS: &[(&str, fn())] = &[
    (
        "c_example::the_c_example_agrees_with_rust_under_valgrind",
        c_example::the_c_example_agrees_with_rust_under_valgrind,
    ),
    (
        "c_hostile::the_c_abi_keeps_the_hostile_use_contract",
        c_hostile::the_c_abi_keeps_the_hostile_use_contract,
    ),
    (
        "spirv_consumer::committed_spirv_reproduces_the_cpu_sampler",
        spirv_consumer::committed_spirv_reproduces_the_cpu_sampler,
    ),
];

/// libtest flags that take a value, which must not be read as a name filter.
const FLAGS_WITH_VALUE: &[&str] = &[
    "--test-threads",
    "--skip",
    "--format",
    "--color",
    "--logfile",
    "-Z",
];

fn main() -> ExitCode {
    let os_args: Vec<OsString> = std::env::args_os().collect();
    if let Some(code) = pin_volume::vdb::serve_vdb_worker_if_asked(&os_args) {
        return code;
    }
    let args: Vec<String> = os_args[1..]
        .iter()
        .map(|a| a.to_string_lossy().into_owned())
        .collect();
    let (mut filters, mut skips) = (Vec::new(), Vec::new());
    let mut it = args.iter();
    while let Some(a) = it.next() {
        if FLAGS_WITH_VALUE.contains(&a.as_str()) {
            let value = it.next();
            if a == "--skip" {
                skips.extend(value.cloned());
            }
        } else if !a.starts_with('-') {
            filters.push(a.clone());
        }
    }
    let exact = args.iter().any(|a| a == "--exact");
    let matches = |name: &str, pattern: &String| {
        if exact {
            name == pattern
        } else {
            name.contains(pattern.as_str())
        }
    };
    let chosen: Vec<&(&str, fn())> = TESTS
        .iter()
        .filter(|(name, _)| filters.is_empty() || filters.iter().any(|f| matches(name, f)))
        .filter(|(name, _)| !skips.iter().any(|s| matches(name, s)))
        .collect();
    if args.iter().any(|a| a == "--list") {
        for (name, _) in &chosen {
            println!("{name}: test");
        }
        return ExitCode::SUCCESS;
    }
    println!("\nrunning {} tests", chosen.len());
    let mut failed = Vec::new();
    for (name, test) in &chosen {
        println!("test {name} ...");
        match catch_unwind(*test) {
            Ok(()) => println!("test {name} ... ok"),
            Err(_) => {
                println!("test {name} ... FAILED");
                failed.push(*name);
            }
        }
    }
    let filtered = TESTS.len() - chosen.len();
    let passed = chosen.len() - failed.len();
    if failed.is_empty() {
        println!("\ntest result: ok. {passed} passed; 0 failed; {filtered} filtered out");
        ExitCode::SUCCESS
    } else {
        println!("\nfailures:\n    {}", failed.join("\n    "));
        println!(
            "\ntest result: FAILED. {passed} passed; {} failed; {filtered} filtered out",
            failed.len()
        );
        ExitCode::from(101)
    }
}
