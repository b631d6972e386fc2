//! `treelod verify FILE...`: open every file and run the full check of format spec §9.2.
//!
//! Every file is checked, even after a failure; each valid one gets a line `FILE: ok (counters)` on
//! stdout, each invalid one a line `error: FILE: reason` on stderr, in the order the files were
//! given. The exit code is that of the first failure.
//!
//! Files are checked side by side, `--jobs` at once (default: the available cores), each worker
//! taking the next file in the list; a file's lines are printed once every file before it is done,
//! so at most `--jobs` containers are held decoded at once, and the lines of a file that is done
//! wait only for the slower files before it.

use std::path::PathBuf;
use std::sync::{Mutex, PoisonError};

use treelod_format::{ErrorClass, VerifyReport};

use crate::report::{self, Failed};
use crate::workers;

/// Arguments of `treelod verify`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// The containers to check.
    #[arg(required = true, value_name = "FILE")]
    pub files: Vec<PathBuf>,
    /// Files checked at once (default: the available cores). Each one is held decoded while it
    /// is checked.
    #[arg(short, long, value_name = "N", value_parser = clap::value_parser!(u32).range(1..=4096))]
    pub jobs: Option<u32>,
}

/// What checking one file found: its `ok` line, or its error message and class.
type Outcome = Result<String, (String, ErrorClass)>;

/// Runs `treelod verify`.
pub fn run(args: &Args) -> Result<(), Failed> {
    // The outcomes not printed yet, and the first file whose lines are not printed.
    let printing = Mutex::new(Printing { outcomes: vec![None; args.files.len()], next: 0, first_failure: None });
    // A check runs on its worker alone, so the pool needs no more threads than files.
    let files = u32::try_from(args.files.len()).unwrap_or(u32::MAX);
    workers::on_workers(args.jobs.map(|n| n.min(files)), args.files.len(), |index| {
        let outcome = check(&args.files[index]);
        printing.lock().unwrap_or_else(PoisonError::into_inner).done(index, outcome);
    })?;
    let printing = printing.into_inner().unwrap_or_else(PoisonError::into_inner);
    printing.first_failure.map_or(Ok(()), Err)
}

/// Opens and checks one file, printing nothing.
fn check(path: &std::path::Path) -> Outcome {
    let container = report::open_unreported(path)?;
    let summary = treelod_format::verify(&container).map_err(|e| report::file_error_message(path, &e))?;
    Ok(ok_line(&path.display().to_string(), &summary))
}

/// The files' outcomes, printed in list order as they become ready.
struct Printing {
    outcomes: Vec<Option<Outcome>>,
    /// The first file not printed yet.
    next: usize,
    first_failure: Option<Failed>,
}

impl Printing {
    /// Keeps file `index`'s outcome, then prints every outcome ready from the first unprinted.
    fn done(&mut self, index: usize, outcome: Outcome) {
        if let Some(slot) = self.outcomes.get_mut(index) {
            *slot = Some(outcome);
        }
        while let Some(outcome) = self.outcomes.get_mut(self.next).and_then(Option::take) {
            self.next += 1;
            let printed = match outcome {
                Ok(line) => report::write_stdout(&line),
                Err((message, class)) => {
                    report::print_error(&message);
                    Err(Failed { class })
                }
            };
            if let Err(failed) = printed {
                self.first_failure.get_or_insert(failed);
            }
        }
    }
}

/// The line printed for a valid file: `FILE: ok (counters)`.
///
/// The counters say what was checked: sections and bytes under checksum, cells, every record kind
/// that has records, and the leaves whose exact cut (spec §10) was verified.
fn ok_line(file: &str, report: &VerifyReport) -> String {
    let records: Vec<String> = [
        (report.vertices, "vertex", "vertices"),
        (report.triangles, "triangle", "triangles"),
        (report.points, "point", "points"),
        (report.materials, "material", "materials"),
        (report.images, "image", "images"),
        (report.ellipsoids, "ellipsoid", "ellipsoids"),
        (report.lines, "line", "lines"),
        (report.far_lines, "far line", "far lines"),
        (report.planes, "plane", "planes"),
        (report.plane_leaves, "plane leaf", "plane leaves"),
        (report.plane_diffuse, "plane diffuse record", "plane diffuse records"),
        (report.prune_leaves, "pruned leaf", "pruned leaves"),
        (report.prune_triangles, "pruned triangle", "pruned triangles"),
        (report.curve_samples, "curve sample", "curve samples"),
        (report.lod_levels, "LoD level", "LoD levels"),
        (report.lod_triangles, "LoD triangle", "LoD triangles"),
        (report.billboards, "billboard quad", "billboard quads"),
        (report.octahedral, "octahedral impostor", "octahedral impostors"),
        (report.octahedral_depth, "octahedral depth plane", "octahedral depth planes"),
        (report.octahedral_normals, "octahedral normal grid", "octahedral normal grids"),
        (report.octahedral_normal_grids, "octahedral normal grid", "octahedral normal grids"),
        (report.calibration, "calibration record", "calibration records"),
        (report.calibration_elevations, "calibration record per elevation", "calibration records per elevation"),
        (report.chain_calibration, "chain calibration record", "chain calibration records"),
        (report.calibration_added, "added-technique calibration record", "added-technique calibration records"),
        (
            report.calibration_elevations_added,
            "added-technique calibration record per elevation",
            "added-technique calibration records per elevation",
        ),
        (report.calibration_flip, "FLIP calibration record", "FLIP calibration records"),
        (report.chain_calibration_flip, "chain FLIP calibration record", "chain FLIP calibration records"),
        (report.ao, "ambient-occlusion byte", "ambient-occlusion bytes"),
        (report.point_facing, "point facing byte", "point facing bytes"),
    ]
    .into_iter()
    .filter(|&(n, _, _)| n > 0)
    .map(|(n, one, many)| count(n, one, many))
    .collect();
    let records = if records.is_empty() { "no records".to_owned() } else { records.join(", ") };
    format!(
        "{file}: ok ({} sections, {} bytes checksummed; {} cells; {records}; exact cut of {})\n",
        report.sections,
        report.checksummed_bytes,
        report.cells,
        count(report.cut_leaves, "leaf", "leaves"),
    )
}

/// `n` and the noun, singular for one.
fn count(n: u64, one: &str, many: &str) -> String {
    format!("{n} {}", if n == 1 { one } else { many })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ok_line_lists_the_non_zero_record_counts() {
        let mut report = VerifyReport::default();
        report.sections = 4;
        report.checksummed_bytes = 512;
        report.cells = 2;
        report.triangles = 1;
        report.points = 3;
        report.cut_leaves = 1;
        assert_eq!(
            ok_line("a.treelod", &report),
            "a.treelod: ok (4 sections, 512 bytes checksummed; 2 cells; 1 triangle, 3 points; exact cut of 1 leaf)\n"
        );
        assert!(ok_line("b", &VerifyReport::default()).contains("; no records;"));
        // Every kind verify checks is counted, the far lines, the planes' diffuse records and the
        // octahedral impostors too.
        report.far_lines = 2;
        report.plane_diffuse = 1;
        report.billboards = 4;
        report.octahedral = 2;
        report.ao = 5;
        let line = ok_line("c", &report);
        assert!(
            line.contains("2 far lines")
                && line.contains("1 plane diffuse record,")
                && line.contains("4 billboard quads, 2 octahedral impostors,")
                && line.contains("5 ambient-occlusion bytes"),
            "{line}"
        );
        report.octahedral = 1;
        assert!(ok_line("d", &report).contains("4 billboard quads, 1 octahedral impostor,"));
        // The octahedral views' depth planes (spec §6.13.2), after the impostors.
        report.octahedral_depth = 4;
        assert!(ok_line("d", &report).contains("1 octahedral impostor, 4 octahedral depth planes, 5 ambient"));
        report.octahedral_depth = 1;
        assert!(ok_line("d", &report).contains("1 octahedral impostor, 1 octahedral depth plane, 5 ambient"));
        // Where the octahedral views' normals lie (spec §6.13.3), after the depth planes.
        report.octahedral_depth = 4;
        report.octahedral_normals = 2;
        assert!(ok_line("d", &report).contains("4 octahedral depth planes, 2 octahedral normal grids, 5 ambient"));
        report.octahedral_normals = 1;
        assert!(ok_line("d", &report).contains("4 octahedral depth planes, 1 octahedral normal grid, 5 ambient"));
        report.octahedral_normals = 0;
        // 1.16's grids (OCTAHEDRAL_NORMAL_GRIDS) read as 1.15's, in the same place: a file holds
        // one of the two kinds.
        report.octahedral_normal_grids = 2;
        assert!(ok_line("d", &report).contains("4 octahedral depth planes, 2 octahedral normal grids, 5 ambient"));
        report.octahedral_normal_grids = 1;
        assert!(ok_line("d", &report).contains("4 octahedral depth planes, 1 octahedral normal grid, 5 ambient"));
        report.octahedral_normal_grids = 0;
        report.octahedral_depth = 0;
        // The points' facing (spec §6.5.1), after the ambient occlusion.
        report.point_facing = 3;
        assert!(ok_line("d", &report).contains("5 ambient-occlusion bytes, 3 point facing bytes;"));
        report.point_facing = 0;
        // The calibration of the techniques added after 1.11, over every view and per elevation.
        report.calibration = 9;
        report.calibration_added = 3;
        report.calibration_elevations_added = 12;
        let line = ok_line("e", &report);
        assert!(
            line.contains(
                "9 calibration records, 3 added-technique calibration records, 12 added-technique calibration \
                           records per elevation, 5 ambient-occlusion bytes"
            ),
            "{line}"
        );
        // The calibration's FLIP error (spec §6.19), after the RMSE tables.
        report.calibration_flip = 18;
        assert!(ok_line("f", &report).contains("per elevation, 18 FLIP calibration records, 5 ambient"));
        report.calibration_flip = 1;
        assert!(ok_line("f", &report).contains("per elevation, 1 FLIP calibration record, 5 ambient"));
        // The chain levels' FLIP error (spec §6.20), after the calibration's.
        report.chain_calibration_flip = 9;
        assert!(
            ok_line("f", &report).contains(", 1 FLIP calibration record, 9 chain FLIP calibration records, 5 ambient")
        );
        report.chain_calibration_flip = 1;
        assert!(
            ok_line("f", &report).contains(", 1 FLIP calibration record, 1 chain FLIP calibration record, 5 ambient")
        );
    }
}
