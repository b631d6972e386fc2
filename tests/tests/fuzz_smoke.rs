//! Deterministic, bounded mutation fuzzing that runs in CI on a stable toolchain (cargo-fuzz needs
//! nightly flags; see docs/fuzzing.md): the same targets as `fuzz/`, fed mutations of valid seeds.
//!
//! - `container_open_verify`: `Container::from_bytes` and, when it opens, `verify`. Seeds: the
//!   golden files under `tests/data`, their uncompressed re-encodings and a small synthetic file
//!   with every kind of section. Mutations: byte-level (bit flips, interesting integers, truncation,
//!   insertion, deletion, duplication, splicing of two seeds) and structure-aware (a section's
//!   payload changed and its checksum and the header's recomputed, so the change reaches the
//!   content rules behind them).
//! - `gltf_import_build`: `import_gltf_bytes_with` with small limits and no base directory and, for
//!   what imports, a cheap build (2 × 2 × 2 grid, no occlusion; at most 4096 triangles) whose
//!   container must write and verify. Seeds: the valid documents of `treelod_tests::gltf`, as
//!   `.gltf` and `.glb`. Mutations: structure-aware on the JSON (a value replaced by an interesting
//!   number — 0, −1, 2^31, 2^32, 1e39, … — or string — huge, a path outside, a data URI —, removed,
//!   duplicated, swapped with another), byte flips in the binary chunk, and the byte-level ones.
//!
//! Every input runs under `catch_unwind` with its peak heap measured; a panic, a peak over the
//! bound, a slow input or (for glTF) a built container that does not verify is a failure. Each
//! iteration's mutations come from its own seed, `SplitMix64(base ^ target ^ iteration)`: a failure
//! prints the seed and iteration and writes the input to `target/fuzz-smoke/<target>/`.
//!
//! Environment: `TREELOD_FUZZ_ITERATIONS` (iterations per target, default chosen for ≤ ~30 s per
//! target on 2 cores in the test profile), `TREELOD_FUZZ_SEED` (the base seed, decimal or `0x`
//! hex), `TREELOD_FUZZ_MAX_FAILURES` (failures reported before a target stops, default 10),
//! `TREELOD_FUZZ_INPUT` (a file: run it through both targets instead of fuzzing, to reproduce a
//! failure).

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use serde_json::{Value, json};
use treelod_build::{BuildConfig, BuildError, ImportLimits, Placed};
use treelod_format::{Compression, Container, ContainerData, verify};
use treelod_tests::alloc::{CountingAllocator, counting, exclusive, peak_during};
use treelod_tests::raw::RawFile;
use treelod_tests::{SplitMix64, SyntheticOptions, gltf, synthetic};

#[global_allocator]
static ALLOCATOR: CountingAllocator = CountingAllocator;

const MIB: usize = 1 << 20;
/// An input slower than this is a failure (a hang in the making).
const SLOW: Duration = Duration::from_secs(10);
/// Failures reported before a target stops, unless `TREELOD_FUZZ_MAX_FAILURES` says otherwise.
const MAX_FAILURES: u64 = 10;
const DEFAULT_SEED: u64 = 0x7EE1_0D5E_ED00_0028;

// ---------------------------------------------------------------------------------------------
// The driver

fn env_u64(name: &str) -> Option<u64> {
    let text = std::env::var(name).ok()?;
    let text = text.trim();
    let parsed = match text.strip_prefix("0x") {
        Some(hex) => u64::from_str_radix(hex, 16),
        None => text.parse(),
    };
    Some(parsed.unwrap_or_else(|e| panic!("{name}={text}: {e}")))
}

/// FNV-1a of the target's name, so targets draw different sequences from one base seed.
fn name_hash(name: &str) -> u64 {
    name.bytes().fold(0xCBF2_9CE4_8422_2325, |h, b| (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01B3))
}

fn out_dir(target: &str) -> PathBuf {
    let root = std::env::var_os("CARGO_TARGET_DIR")
        .map_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../target"), PathBuf::from);
    root.join("fuzz-smoke").join(target)
}

/// What one input did, for the summary.
#[derive(Default)]
struct Tally {
    accepted: u64,
    refused: u64,
}

/// Runs `iterations` mutated inputs through `check`, which returns `Ok(true)` for an accepted
/// input, `Ok(false)` for a refused one and `Err` for a failure; `peak_bound` gives the heap an
/// input of a length may use.
fn fuzz(
    target: &str,
    default_iterations: u64,
    mutate: &dyn Fn(&mut SplitMix64) -> Vec<u8>,
    check: &dyn Fn(&[u8]) -> Result<bool, String>,
    peak_bound: fn(usize) -> usize,
) {
    assert!(counting(), "the counting allocator is installed");
    if let Some(file) = std::env::var_os("TREELOD_FUZZ_INPUT") {
        let bytes = std::fs::read(&file).expect("reads TREELOD_FUZZ_INPUT");
        let (result, peak) = peak_during(|| catch_unwind(AssertUnwindSafe(|| check(&bytes))));
        eprintln!("{target}: {}: {:?}, peak heap {} bytes", Path::new(&file).display(), result, peak.process);
        assert!(matches!(result, Ok(Ok(_))), "{target}: the input fails");
        assert!(peak.process <= peak_bound(bytes.len()), "{target}: peak heap {} bytes", peak.process);
        return;
    }
    let iterations = env_u64("TREELOD_FUZZ_ITERATIONS").unwrap_or(default_iterations);
    let base = env_u64("TREELOD_FUZZ_SEED").unwrap_or(DEFAULT_SEED);
    let max_failures = env_u64("TREELOD_FUZZ_MAX_FAILURES").unwrap_or(MAX_FAILURES).max(1);
    let start = Instant::now();
    let mut tally = Tally::default();
    let mut failures = Vec::new();
    let mut slowest = (Duration::ZERO, 0);
    let mut largest_peak = 0;
    let mut ran = 0;
    for iteration in 0..iterations {
        ran += 1;
        let seed = base ^ name_hash(target) ^ iteration.wrapping_mul(0x9E37_79B9_7F4A_7C15);
        let input = mutate(&mut SplitMix64::new(seed));
        let began = Instant::now();
        let (result, peak) = peak_during(|| catch_unwind(AssertUnwindSafe(|| check(&input))));
        let took = began.elapsed();
        slowest = slowest.max((took, iteration));
        largest_peak = largest_peak.max(peak.process);
        let failure = match result {
            Err(_) => Some("panicked".to_owned()),
            Ok(Err(reason)) => Some(reason),
            Ok(Ok(_)) if peak.process > peak_bound(input.len()) => Some(format!(
                "peak heap {} bytes for a {}-byte input (bound {})",
                peak.process,
                input.len(),
                peak_bound(input.len())
            )),
            Ok(Ok(_)) if took > SLOW => Some(format!("took {took:?}")),
            Ok(Ok(true)) => {
                tally.accepted += 1;
                None
            }
            Ok(Ok(false)) => {
                tally.refused += 1;
                None
            }
        };
        if let Some(reason) = failure {
            let dir = out_dir(target);
            let file = dir.join(format!("seed-{base:016x}-iteration-{iteration}.bin"));
            let written = std::fs::create_dir_all(&dir).and_then(|()| std::fs::write(&file, &input));
            let line = format!(
                "{target}: iteration {iteration} (TREELOD_FUZZ_SEED=0x{base:x}, input seed 0x{seed:016x}): {reason}; \
                 input {} ({} bytes{}); reproduce with TREELOD_FUZZ_INPUT={} cargo nextest run -p treelod-tests \
                 --test fuzz_smoke {target}",
                file.display(),
                input.len(),
                if written.is_ok() { "" } else { ", NOT written" },
                file.display()
            );
            eprintln!("{line}");
            failures.push(line);
            if failures.len() as u64 >= max_failures {
                break;
            }
        }
    }
    eprintln!(
        "{target}: {ran} of {iterations} inputs in {:.1?} ({} accepted, {} refused, {} failed); slowest {:.1?} (iteration {}), \
         largest peak heap {largest_peak} bytes",
        start.elapsed(),
        tally.accepted,
        tally.refused,
        failures.len(),
        slowest.0,
        slowest.1,
    );
    assert!(failures.is_empty(), "{} failures:\n{}", failures.len(), failures.join("\n"));
}

// ---------------------------------------------------------------------------------------------
// Byte-level mutations

/// Integers a parser must survive wherever a length, count, offset or index is read.
const INTERESTING_U32: [u32; 14] =
    [0, 1, 2, 3, 4, 16, 255, 256, 0x7FFF, 0xFFFF, 0x7FFF_FFFF, 0x8000_0000, 0xFFFF_FFFE, 0xFFFF_FFFF];

fn pick<'a, T>(rng: &mut SplitMix64, items: &'a [T]) -> &'a T {
    &items[rng.below(u32::try_from(items.len()).expect("few")) as usize]
}

fn below(rng: &mut SplitMix64, n: usize) -> usize {
    rng.below(u32::try_from(n).unwrap_or(u32::MAX)) as usize
}

/// One byte-level mutation of `bytes`; `others` supplies splices.
fn mutate_bytes(rng: &mut SplitMix64, bytes: &mut Vec<u8>, others: &[Vec<u8>]) {
    if bytes.is_empty() {
        let n = 1 + below(rng, 16);
        bytes.extend(rng.bytes(n));
        return;
    }
    let len = bytes.len();
    match rng.below(9) {
        0 => {
            for _ in 0..=rng.below(8) {
                let at = below(rng, len);
                bytes[at] ^= 1 << rng.below(8);
            }
        }
        1 => {
            let at = below(rng, len);
            bytes[at] = *pick(rng, &[0, 1, 0x7F, 0x80, 0xFF, b'0', b'-', b'"', b'{', b'[']);
        }
        2 => {
            let value = if rng.chance(0.2) {
                u32::try_from(len).unwrap_or(u32::MAX).wrapping_add(rng.below(3))
            } else {
                *pick(rng, &INTERESTING_U32)
            };
            let at = below(rng, len.saturating_sub(3)) & !3;
            let end = (at + 4).min(len);
            bytes[at..end].copy_from_slice(&value.to_le_bytes()[..end - at]);
        }
        3 => bytes.truncate(below(rng, len)),
        4 => {
            let at = below(rng, len + 1);
            let n = 1 + below(rng, 16);
            let inserted = rng.bytes(n);
            bytes.splice(at..at, inserted);
        }
        5 => {
            let at = below(rng, len);
            let end = (at + 1 + below(rng, 64)).min(len);
            bytes.drain(at..end);
        }
        6 => {
            let at = below(rng, len);
            let end = (at + 1 + below(rng, 256)).min(len);
            let chunk = bytes[at..end].to_vec();
            let to = below(rng, len + 1);
            bytes.splice(to..to, chunk);
        }
        7 => {
            let other = pick(rng, others);
            let cut = below(rng, len + 1);
            let from = below(rng, other.len() + 1);
            bytes.truncate(cut);
            bytes.extend_from_slice(&other[from..]);
        }
        _ => {
            let at = below(rng, len);
            let end = (at + 1 + below(rng, 32)).min(len);
            let fill = *pick(rng, &[0u8, 0xFF]);
            bytes[at..end].fill(fill);
        }
    }
}

fn mutate_bytes_n(rng: &mut SplitMix64, bytes: &mut Vec<u8>, others: &[Vec<u8>]) {
    for _ in 0..=rng.below(3) {
        mutate_bytes(rng, bytes, others);
    }
}

// ---------------------------------------------------------------------------------------------
// The container target

fn container_seeds() -> Vec<Vec<u8>> {
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("data");
    let mut files: Vec<PathBuf> = std::fs::read_dir(&data)
        .expect("tests/data")
        .flat_map(|dir| std::fs::read_dir(dir.expect("an entry").path()).expect("a version directory"))
        .map(|entry| entry.expect("an entry").path())
        .filter(|path| path.extension().is_some_and(|e| e == "treelod"))
        .collect();
    files.sort();
    let mut seeds = Vec::new();
    for file in files {
        let bytes = std::fs::read(&file).expect("reads a golden file");
        let container = Container::from_bytes(&bytes).expect("a golden file opens");
        let plain = ContainerData::from_container(&container).to_bytes(Compression::None).expect("writes");
        seeds.push(bytes);
        seeds.push(plain);
    }
    let small = SyntheticOptions::small();
    let data = synthetic(28, &small);
    seeds.push(data.to_bytes(Compression::None).expect("writes"));
    seeds.push(data.to_bytes(Compression::Zstd { level: 3 }).expect("writes"));
    seeds
}

/// A seed with one section's payload changed and the checksums recomputed.
fn mutate_section(rng: &mut SplitMix64, seed: &[u8], others: &[Vec<u8>]) -> Vec<u8> {
    let mut file = RawFile::new(seed.to_vec());
    let index = below(rng, file.section_count());
    let payload = file.payload_mut(index);
    if payload.is_empty() {
        return file.into_bytes();
    }
    for _ in 0..=rng.below(4) {
        let len = payload.len();
        if rng.chance(0.5) && len >= 4 {
            let at = below(rng, len - 3) & !3;
            let value = *pick(rng, &INTERESTING_U32);
            // As an integer, or as a float: NaN, infinity, a huge or a negative value.
            let word = if rng.chance(0.3) {
                pick(rng, &[f32::NAN, f32::INFINITY, -1.0, 1e30, 0.0, -0.0, f32::MIN_POSITIVE]).to_bits()
            } else {
                value
            };
            payload[at..at + 4].copy_from_slice(&word.to_le_bytes());
        } else {
            let at = below(rng, len);
            payload[at] ^= 1 << rng.below(8);
        }
    }
    file.reseal_section(index);
    let mut bytes = file.into_bytes();
    if rng.chance(0.1) {
        mutate_bytes(rng, &mut bytes, others);
    }
    bytes
}

fn check_container(bytes: &[u8]) -> Result<bool, String> {
    match Container::from_bytes(bytes) {
        Ok(container) => Ok(verify(&container).is_ok()),
        Err(e) if e.to_string().is_empty() => Err("an empty error message".into()),
        Err(_) => Ok(false),
    }
}

#[test]
fn container_open_verify() {
    let _alone = exclusive();
    let seeds = container_seeds();
    let mutate = |rng: &mut SplitMix64| {
        let seed = pick(rng, &seeds);
        if rng.chance(0.5) {
            mutate_section(rng, seed, &seeds)
        } else {
            let mut bytes = seed.clone();
            mutate_bytes_n(rng, &mut bytes, &seeds);
            bytes
        }
    };
    // As tests/tests/hostile.rs: never more than 64 × the file plus a little.
    fuzz("container_open_verify", 300_000, &mutate, &check_container, |len| 64 * len + 4 * MIB);
}

// ---------------------------------------------------------------------------------------------
// The glTF target

/// Values that break glTF readers: component types, counts around 2^31 and 2^32, overflowing
/// floats, indices just past the end.
fn interesting_value(rng: &mut SplitMix64) -> Value {
    match rng.below(4) {
        0 => json!(*pick(
            rng,
            &[
                0i64,
                -1,
                1,
                2,
                3,
                4,
                5,
                7,
                8,
                24,
                25,
                255,
                256,
                65535,
                65536,
                5120,
                5121,
                5122,
                5123,
                5125,
                5126,
                34962,
                34963,
                0x7FFF_FFFF,
                0x8000_0000,
                0xFFFF_FFFF,
                0x1_0000_0000,
                i64::MAX,
                i64::MIN,
            ]
        )),
        1 => json!(*pick(rng, &[1e39, -1e39, 1e-45, 0.5, -0.0, 1e308, 3.4e38])),
        2 => json!(
            pick(
                rng,
                &[
                    "",
                    "VEC2",
                    "VEC3",
                    "VEC4",
                    "SCALAR",
                    "MAT4",
                    "MASK",
                    "BLEND",
                    "image/jpeg",
                    "image/png",
                    "image/gif",
                    "../outside.bin",
                    "/dev/zero",
                    "/etc/passwd",
                    "data:application/octet-stream;base64,",
                    "data:,",
                    "%2e%2e/x.bin",
                    "KHR_draco_mesh_compression",
                    "KHR_mesh_quantization",
                    "KHR_texture_transform",
                    "TEXCOORD_0",
                    "glTF",
                ]
            )
            .to_owned()
        ),
        _ => match rng.below(6) {
            0 => Value::Null,
            1 => json!(true),
            2 => json!([]),
            3 => json!({}),
            4 => json!([0, 0]),
            _ => json!("x".repeat(1 << (10 + rng.below(11)))),
        },
    }
}

/// The JSON pointers of every value under `value`.
fn pointers(value: &Value, at: &str, out: &mut Vec<String>) {
    out.push(at.to_owned());
    match value {
        Value::Object(map) => {
            for (key, child) in map {
                pointers(child, &format!("{at}/{}", key.replace('~', "~0").replace('/', "~1")), out);
            }
        }
        Value::Array(items) => {
            for (i, child) in items.iter().enumerate() {
                pointers(child, &format!("{at}/{i}"), out);
            }
        }
        _ => {}
    }
}

/// One structure-aware mutation of a glTF JSON document.
fn mutate_json(rng: &mut SplitMix64, json: &mut Value) {
    let mut all = Vec::new();
    pointers(json, "", &mut all);
    // Prefer leaves (numbers and strings), where the indices, counts and types are.
    let target = pick(rng, &all).clone();
    let (parent, key) = target.rsplit_once('/').unwrap_or(("", ""));
    match rng.below(8) {
        0..=2 => {
            let value = interesting_value(rng);
            if let Some(slot) = json.pointer_mut(&target) {
                *slot = value;
            }
        }
        3 => {
            // Off by one, or scaled by a power of two.
            if let Some(slot) = json.pointer_mut(&target)
                && let Some(n) = slot.as_i64()
            {
                *slot = json!(match rng.below(3) {
                    0 => n.wrapping_add(1),
                    1 => n.wrapping_sub(1),
                    _ => n.wrapping_mul(1 << (1 + rng.below(31))),
                });
            }
        }
        4 => {
            // Remove the value from its object or array.
            match json.pointer_mut(parent) {
                Some(Value::Object(map)) => {
                    let key = key.replace("~1", "/").replace("~0", "~");
                    map.remove(&key);
                }
                Some(Value::Array(items)) => {
                    if let Ok(i) = key.parse::<usize>()
                        && i < items.len()
                    {
                        items.remove(i);
                    }
                }
                _ => {}
            }
        }
        5 => {
            // Duplicate an array element (a child listed twice, an accessor repeated).
            if let Some(Value::Array(items)) = json.pointer_mut(parent)
                && let Ok(i) = key.parse::<usize>()
                && let Some(item) = items.get(i).cloned()
            {
                for _ in 0..=rng.below(3) {
                    items.push(item.clone());
                }
            }
        }
        _ => {
            // Put another value of the document here (indices swapped, an object moved).
            let other = pick(rng, &all).clone();
            if let Some(value) = json.pointer(&other).cloned()
                && !target.starts_with(&other)
                && let Some(slot) = json.pointer_mut(&target)
            {
                *slot = value;
            }
        }
    }
}

struct GltfSeed {
    json: Value,
    /// The binary chunk of a GLB seed; `None` for a `.gltf`.
    bin: Option<Vec<u8>>,
}

fn gltf_seeds() -> (Vec<GltfSeed>, Vec<Vec<u8>>) {
    let files = gltf::valid_files();
    let mut seeds = Vec::new();
    for (_, bytes) in &files {
        let (json, bin) = match gltf::split_glb(bytes) {
            Some((json, bin)) => (json, Some(bin.unwrap_or_default())),
            None => (bytes.clone(), None),
        };
        seeds.push(GltfSeed { json: serde_json::from_slice(&json).expect("a valid seed"), bin });
    }
    (seeds, files.into_iter().map(|(_, bytes)| bytes).collect())
}

fn mutate_gltf(rng: &mut SplitMix64, seeds: &[GltfSeed], raw: &[Vec<u8>]) -> Vec<u8> {
    let seed = pick(rng, seeds);
    if rng.chance(0.15) {
        // Byte-level only.
        let mut bytes = pick(rng, raw).clone();
        mutate_bytes_n(rng, &mut bytes, raw);
        return bytes;
    }
    let mut json = seed.json.clone();
    for _ in 0..=rng.below(3) {
        mutate_json(rng, &mut json);
    }
    let text = serde_json::to_vec(&json).expect("serialises");
    let mut bytes = match &seed.bin {
        Some(bin) => {
            let mut bin = bin.clone();
            if rng.chance(0.2) && !bin.is_empty() {
                for _ in 0..=rng.below(4) {
                    let at = below(rng, bin.len());
                    bin[at] = rng.bytes(1)[0];
                }
            }
            gltf::glb(&text, Some(&bin))
        }
        None => text,
    };
    if rng.chance(0.1) {
        mutate_bytes(rng, &mut bytes, raw);
    }
    bytes
}

/// Limits small enough that no input can make an iteration slow or large.
fn fuzz_limits() -> ImportLimits {
    ImportLimits {
        max_decoded_bytes: 32 << 20,
        max_image_pixels: 1 << 20,
        max_instances: 4096,
        max_triangles: 1 << 16,
        allow_external_uris: false,
    }
}

/// Imports `bytes`; builds what imports (at most 4096 triangles), writes and verifies the container.
fn import_and_build(bytes: &[u8]) -> Result<bool, String> {
    let name = if bytes.starts_with(b"glTF") { "fuzz.glb" } else { "fuzz.gltf" };
    let scene = match treelod_build::import_gltf_bytes_with(bytes, Path::new(name), None, &fuzz_limits()) {
        Ok(scene) => scene,
        Err(e) => {
            let message = e.to_string();
            return if message.starts_with(name) {
                Ok(false)
            } else {
                Err(format!("a message not naming the input: {message}"))
            };
        }
    };
    let triangles: usize = scene.parts.iter().map(|p| p.triangles.len()).sum();
    if triangles > 4096 {
        return Ok(true);
    }
    let config = BuildConfig { grid: Some([2, 2, 2]), ..BuildConfig::default() };
    let trees = [Placed { scene: &scene, translation: glam::Vec3::ZERO }];
    match treelod_build::build_block("fuzz", &trees, &config, "treelod-tests fuzz_smoke") {
        Ok(output) => {
            let bytes =
                output.data.to_bytes(Compression::None).map_err(|e| format!("the container does not write: {e}"))?;
            let container =
                Container::from_bytes(&bytes).map_err(|e| format!("the built container does not open: {e}"))?;
            verify(&container).map_err(|e| format!("the built container does not verify: {e}"))?;
            Ok(true)
        }
        Err(BuildError::Setting(e)) => Err(format!("a setting error from an input: {e}")),
        Err(_) => Ok(true),
    }
}

#[test]
fn gltf_import_build() {
    let _alone = exclusive();
    let (seeds, raw) = gltf_seeds();
    for (i, bytes) in raw.iter().enumerate() {
        assert_eq!(import_and_build(bytes), Ok(true), "seed {i} imports and builds");
    }
    let mutate = |rng: &mut SplitMix64| mutate_gltf(rng, &seeds, &raw);
    fuzz("gltf_import_build", 50_000, &mutate, &import_and_build, |len| 64 * MIB + 4 * len);
}
