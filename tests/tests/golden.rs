//! Golden files of format versions 1.0 to 1.18 (`tests/data/v1_0` to `tests/data/v1_18`): every file
//! opens and verifies with its version in its header, the
//! minimal file (and 1.13's octahedral depth planes) decodes to literal values written out here (so
//! a change in reading is caught even if writing changed the same way), and spec §13.1 holds the
//! minimal file's hex dump.

use std::path::PathBuf;

use treelod_format::{
    BlockRecord, CellRecord, Compression, Container, ContainerData, FLAG_ZSTD, FlipCalibrationRecord, LineRecord,
    MaterialInfo, MaterialRecord, Metadata, NO_IMAGE, OctahedralDepthRecord, OctahedralNormalRecord,
    PlaneDiffuseRecord, PointRecord, Range, SectionKind, Setting, Source, Tree, TriangleRecord, VertexRecord,
    calibration_technique, far_switch, far_threshold, image_format, leaf_slots, plane_leaf_bases, verify,
};
use treelod_tests::{
    SPEC_EXAMPLE_BEGIN, SPEC_EXAMPLE_END, golden_dir, golden_dir_of, golden_files, spec_hex_dump, spec_path,
};

fn golden(name: &str) -> PathBuf {
    golden_dir().join(name)
}

fn open(name: &str) -> Container {
    Container::open(golden(name)).unwrap_or_else(|e| panic!("{name}: {e}"))
}

#[test]
fn every_golden_file_opens_and_verifies() {
    for minor in [0u16, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16, 17, 18] {
        golden_files_of_version_open_and_verify(minor);
    }
}

#[expect(clippy::unwrap_used, reason = "a test helper")]
fn golden_files_of_version_open_and_verify(minor: u16) {
    let dir = golden_dir_of(minor);
    let mut names: Vec<String> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".treelod"))
        .collect();
    names.sort();
    for recipe in golden_files().iter().filter(|r| r.minor == minor) {
        assert!(names.iter().any(|n| n == recipe.name), "golden file v1_{minor}/{} is missing", recipe.name);
    }
    for name in &names {
        let path = dir.join(name);
        let container = Container::open(&path).unwrap_or_else(|e| panic!("{name}: {e}"));
        verify(&container).unwrap_or_else(|e| panic!("{name}: {e}"));
        let header = container.header();
        assert_eq!((header.major, header.minor), (1, minor), "v1_{minor}/{name}");
        // The same content read from memory equals the mapped file's.
        let bytes = std::fs::read(&path).unwrap();
        let from_memory = Container::from_bytes(&bytes).unwrap();
        let data = ContainerData::from_container(&container);
        assert_eq!(ContainerData::from_container(&from_memory), data, "{name}");
        // Rewritten uncompressed and read back, the content survives.
        let again = data.to_bytes(Compression::None).unwrap();
        let back = Container::from_bytes(&again).unwrap();
        assert_eq!(ContainerData::from_container(&back), data, "{name}");
        // The writer marks the rewritten file with the same minor: the smallest its kinds need.
        assert_eq!(back.header().minor, minor, "v1_{minor}/{name} rewritten");
    }
}

#[test]
fn uncompressed_golden_files_are_what_the_writer_writes() {
    // The writer is deterministic and writes 1.0 files exactly like these: if this fails, the
    // writer's output changed (the golden files must not be regenerated; see make-golden).
    for name in ["minimal.treelod", "gilet.treelod", "extension.treelod"] {
        let bytes = std::fs::read(golden(name)).unwrap();
        let data = ContainerData::from_container(&Container::from_bytes(&bytes).unwrap());
        assert!(data.to_bytes(Compression::None).unwrap() == bytes, "{name}: the writer no longer reproduces it");
    }
}

#[test]
fn the_minimal_file_decodes_to_these_values() {
    let c = open("minimal.treelod");
    let header = c.header();
    assert_eq!(header.magic, *b"\x89TREELOD\r\n\x1a\n");
    assert_eq!((header.header_size, header.section_count, header.table_offset, header.file_size), (64, 7, 64, 1064));
    assert_eq!((header.flags, header.reserved, header.header_checksum), (0, [0; 16], 0xEC06_C529));
    let table: Vec<(u32, u32, u64, u64, u64, u32, u32)> = c
        .sections()
        .iter()
        .map(|s| {
            let e = s.entry;
            (e.kind, e.flags, e.offset, e.length, e.raw_length, e.record_size, e.checksum)
        })
        .collect();
    assert_eq!(
        table,
        [
            (0x01, 0, 400, 238, 238, 1, 0xF2B6_49F3),
            (0x02, 0, 640, 48, 48, 48, 0xD153_01CD),
            (0x03, 0, 688, 160, 160, 80, 0x472C_5355),
            (0x10, 0, 848, 84, 84, 28, 0xAAFE_5794),
            (0x11, 0, 944, 24, 24, 24, 0x6C7C_0676),
            (0x12, 0, 976, 48, 48, 48, 0xF43C_42AD),
            (0x13, 0, 1024, 40, 40, 40, 0x07EE_E70E),
        ]
    );

    let expected_metadata = Metadata {
        generator: "treelod-tests 0.1.0".into(),
        name: "minimal".into(),
        sources: vec![Source {
            path: "trees/tree-0.glb".into(),
            content_hash: "blake3:2153f064169b27f5e08611c088b8470905911e29d2f9b090789fdcce1ba6386c".into(),
            byte_length: 3_810_352_352,
            unit_scale: 0.01,
        }],
        trees: vec![Tree {
            name: "tree-0".into(),
            source: 0,
            translation: [1.157_694_6, 0.647_479_3, 6.061_854_4],
            bounds_min: [0.817_572_9, 1.680_373_9, 4.073_139],
            bounds_max: [2.048_088_3, 1.700_481, 5.646_667],
        }],
        materials: vec![MaterialInfo { name: "material-0".into(), classified_by: "node".into() }],
        settings: vec![
            Setting { key: "gilet.cluster_max".into(), value: "2".into() },
            Setting { key: "grid".into(), value: "1x1x1".into() },
            Setting { key: "synthetic.seed".into(), value: "1".into() },
        ],
    };
    assert_eq!(c.metadata(), &expected_metadata);
    assert_eq!(
        *c.block(),
        BlockRecord {
            bounds_min: [0.532_492_16, 0.491_563_44, 3.768_021_6],
            bounds_max: [2.143_390_2, 2.102_225, 6.175_257_7],
            grid: [1, 1, 1],
            tree_count: 1,
            flags: 0,
            _pad: 0,
        }
    );
    let empty = |first| Range { first, count: 0 };
    assert_eq!(
        c.cells(),
        [
            CellRecord {
                bounds_min: [1.163_686_8, 1.271_219_3, 4.787_289_6],
                bounds_max: [1.702_643_8, 1.560_854_7, 5.396_181_6],
                triangles: Range { first: 0, count: 1 },
                points: Range { first: 0, count: 1 },
                ellipsoids: empty(0),
                lines: empty(0),
                planes: empty(0),
                prune_leaves: empty(0),
                flags: 0,
                _pad: 0,
            },
            CellRecord {
                bounds_min: [0.0; 3],
                bounds_max: [0.0; 3],
                triangles: empty(1),
                points: empty(1),
                ellipsoids: empty(0),
                lines: empty(0),
                planes: empty(0),
                prune_leaves: empty(0),
                flags: 0,
                _pad: 0,
            },
        ]
    );
    let normal = 0x5E7E_ABF1; // 1585359857
    assert_eq!(
        c.vertices(),
        [
            VertexRecord {
                position: [1.702_643_8, 1.271_219_3, 4.787_289_6],
                normal,
                uv: [0.253_273_13, 0.529_757_4],
                color: 0xFFFF_FFFF,
            },
            VertexRecord {
                position: [1.452_346_1, 1.308_038, 4.985_161_3],
                normal,
                uv: [0.708_179_24, 0.236_360_49],
                color: 3_819_622_847,
            },
            VertexRecord {
                position: [1.163_686_8, 1.560_854_7, 5.396_181_6],
                normal,
                uv: [0.893_939, 0.912_690_16],
                color: 1_398_003_422,
            },
        ]
    );
    assert_eq!(c.triangles(), [TriangleRecord { indices: [0, 1, 2], size: 0.222_833_25, leaf: 0, material: 0 }]);
    assert_eq!(
        c.points(),
        [PointRecord {
            position: [1.439_558_9, 1.380_037_3, 5.056_211],
            radius: 0.111_416_62,
            normal,
            color: 2_476_120_318,
            size: 0.222_833_25,
            lo: 0.0,
            hi: f32::INFINITY,
            leaf_first: 0,
            leaf_count: 1,
            flags: 0,
        }]
    );
    assert_eq!(c.triangles()[0].size.to_bits(), c.points()[0].size.to_bits(), "leaf point size, bit for bit");
    assert_eq!(
        c.materials(),
        [MaterialRecord {
            base_color: [0.877_348_66, 0.523_067_2, 0.285_508_63, 0.896_998_3],
            image: NO_IMAGE,
            alpha_mode: 1,
            alpha_cutoff: 0.605_420_35,
            class: 1,
            flags: 1,
            _pad: 0,
        }]
    );
    assert!(c.images().is_empty() && c.image_data().is_empty() && c.ellipsoids().is_empty() && c.lines().is_empty());
    assert!(c.planes().is_empty() && c.prune_leaves().is_empty() && c.prune_triangles().is_empty());
    assert!(c.prune_scale().is_empty() && c.prune_lambda().is_empty());
}

#[test]
fn the_gilet_file_has_a_grid_of_point_hierarchies() {
    let c = open("gilet.treelod");
    assert_eq!(c.block().grid, [3, 2, 2]);
    let counts: Vec<(u32, u32)> = c.cells().iter().map(|cell| (cell.triangles.count, cell.points.count)).collect();
    assert_eq!(
        counts,
        [(1, 1), (5, 9), (2, 3), (5, 9), (6, 11), (5, 9), (1, 1), (5, 9), (1, 1), (1, 1), (0, 0), (4, 7), (0, 0)]
    );
    assert_eq!(c.images().len(), 1);
}

#[test]
fn the_every_kind_file_has_every_kind_compressed_where_it_pays() {
    let c = open("every-kind-zstd.treelod");
    for kind in SectionKind::KNOWN.into_iter().filter(|k| k.since_minor() == 0) {
        assert!(c.section(kind).is_some(), "{kind} missing");
    }
    for kind in SectionKind::KNOWN.into_iter().filter(|k| k.since_minor() > 0) {
        assert!(c.section(kind).is_none(), "{kind} is not a kind of 1.0");
    }
    let compressed: Vec<SectionKind> =
        c.sections().iter().filter(|s| s.entry.flags & FLAG_ZSTD != 0).map(|s| s.kind()).collect();
    // Everything but BLOCK and CELLS (never compressed), IMAGE_DATA (random texels) and the two
    // 32-byte curves (too small to gain).
    assert_eq!(compressed.len(), 11, "{compressed:?}");
    assert!(!compressed.contains(&SectionKind::BLOCK) && !compressed.contains(&SectionKind::CELLS));
}

#[test]
fn the_1_1_every_kind_file_has_every_kind_of_1_1_and_the_baselines_verify() {
    let path = golden_dir_of(1).join("every-kind-zstd.treelod");
    let c = Container::open(&path).unwrap();
    for kind in SectionKind::KNOWN {
        assert_eq!(c.section(kind).is_some(), kind.since_minor() <= 1, "{kind}");
    }
    assert_eq!(c.header().minor, 1);
    // Two trees, three levels each, and a facing and a crossed quad each.
    let levels: Vec<(u32, u32)> = c.lod_levels().iter().map(|l| (l.tree, l.level)).collect();
    assert_eq!(levels, [(0, 0), (0, 1), (0, 2), (1, 0), (1, 1), (1, 2)]);
    let quads: Vec<(u32, u32)> = c.billboards().iter().map(|b| (b.tree, b.kind)).collect();
    assert_eq!(quads, [(0, 0), (0, 1), (1, 0), (1, 1)]);
    // Without its 1.1 sections the same content is a 1.0 file.
    let mut data = ContainerData::from_container(&c);
    (data.lod_levels, data.lod_triangles, data.billboards) = (Vec::new(), Vec::new(), Vec::new());
    let bytes = data.to_bytes(Compression::None).unwrap();
    assert_eq!(Container::from_bytes(&bytes).unwrap().header().minor, 0);
}

#[test]
fn the_1_2_every_kind_file_has_every_kind_and_ambient_occlusion_for_every_vertex_point_and_plane() {
    let path = golden_dir_of(2).join("every-kind-zstd.treelod");
    let c = Container::open(&path).unwrap();
    for kind in SectionKind::KNOWN {
        assert_eq!(c.section(kind).is_some(), kind.since_minor() <= 2, "{kind}");
    }
    assert_eq!(c.header().minor, 2);
    assert_eq!(
        (c.vertex_ao().len(), c.point_ao().len(), c.plane_ao().len()),
        (c.vertices().len(), c.points().len(), c.planes().len())
    );
    // Without its 1.2 sections the same content is a 1.1 file with the same records.
    let mut data = ContainerData::from_container(&c);
    (data.vertex_ao, data.point_ao, data.plane_ao) = (Vec::new(), Vec::new(), Vec::new());
    let bytes = data.to_bytes(Compression::None).unwrap();
    let older = Container::from_bytes(&bytes).unwrap();
    assert_eq!(older.header().minor, 1);
    assert!(older.vertices() == c.vertices() && older.points() == c.points() && older.planes() == c.planes());
}

#[test]
fn the_1_3_every_kind_file_has_every_kind_and_indirectly_textured_planes() {
    let c = Container::open(golden_dir_of(3).join("every-kind-zstd.treelod")).unwrap();
    for kind in SectionKind::KNOWN {
        assert_eq!(c.section(kind).is_some(), kind.since_minor() <= 3, "{kind}");
    }
    assert_eq!(c.header().minor, 3);
    // Every plane samples the one LEAF_SLOTS image, the last image; PLANE_LEAVES holds every
    // plane's leaves.
    let slots = c.images().len() as u32 - 1;
    assert_eq!(c.images()[slots as usize].format, image_format::LEAF_SLOTS);
    assert!(c.planes().iter().all(|p| p.image == slots));
    assert_eq!(c.plane_leaves().len() as u64, *plane_leaf_bases(c.planes()).last().unwrap());
    assert_eq!(verify(&c).unwrap().indirect_planes, c.planes().len() as u64);
    // Its slots name leaves, and some texels hold two.
    let image = c.images()[slots as usize];
    let texels = &c.image_data()[image.data_offset as usize..][..image.data_length as usize];
    let slot_pairs: Vec<(u16, u16)> = texels.chunks_exact(4).map(|t| leaf_slots([t[0], t[1], t[2], t[3]])).collect();
    assert!(slot_pairs.iter().any(|&(a, b)| a > 0 && b > 0 && a != b));
    // Leaves with a texture rectangle and leaves without (uv_min = uv_max = 0, not clipped).
    assert!(c.plane_leaves().iter().any(|l| l.uv_min == 0 && l.uv_max == 0));
    assert!(c.plane_leaves().iter().any(|l| l.uv_max != 0));

    // The rest is the 1.2 file's content: without PLANE_LEAVES, the LEAF_SLOTS image and the
    // planes' new image and rectangles, the records are those of v1_2.
    let v1_2 =
        ContainerData::from_container(&Container::open(golden_dir_of(2).join("every-kind-zstd.treelod")).unwrap());
    let mut data = ContainerData::from_container(&c);
    assert_eq!(data.ellipsoid_ao.len(), data.ellipsoids.len(), "ELLIPSOID_AO, one byte per ellipsoid");
    data.ellipsoid_ao.clear();
    data.plane_leaves.clear();
    data.images.pop();
    data.image_data.truncate(v1_2.image_data.len());
    for (plane, older) in data.planes.iter_mut().zip(&v1_2.planes) {
        (plane.image, plane.uv_min, plane.uv_max) = (older.image, older.uv_min, older.uv_max);
    }
    assert!(data == v1_2, "v1_3 is v1_2 with indirect texturing and ellipsoid occlusion");
    // So without PLANE_LEAVES the writer marks it 1.2.
    let bytes = data.to_bytes(Compression::None).unwrap();
    assert_eq!(Container::from_bytes(&bytes).unwrap().header().minor, 2);
}

#[test]
fn the_1_4_every_kind_file_has_every_kind_and_line_occlusion() {
    let c = Container::open(golden_dir_of(4).join("every-kind-zstd.treelod")).unwrap();
    for kind in SectionKind::KNOWN {
        assert_eq!(c.section(kind).is_some(), kind.since_minor() <= 4, "{kind}");
    }
    assert_eq!(c.header().minor, 4);
    assert_eq!(c.line_ao().len(), c.lines().len(), "LINE_AO, one byte per line");
    assert!(!c.lines().is_empty());
    // Without LINE_AO it is the 1.3 file, record for record, and the writer marks it 1.3.
    let v1_3 =
        ContainerData::from_container(&Container::open(golden_dir_of(3).join("every-kind-zstd.treelod")).unwrap());
    let mut data = ContainerData::from_container(&c);
    data.line_ao.clear();
    assert!(data == v1_3, "v1_4 is v1_3 with line occlusion");
    let bytes = data.to_bytes(Compression::None).unwrap();
    assert_eq!(Container::from_bytes(&bytes).unwrap().header().minor, 3);
}

#[test]
fn the_1_5_every_kind_file_has_every_kind_and_a_calibration() {
    let c = Container::open(golden_dir_of(5).join("every-kind-zstd.treelod")).unwrap();
    for kind in SectionKind::KNOWN {
        assert_eq!(c.section(kind).is_some(), kind.since_minor() <= 5, "{kind}");
    }
    assert_eq!(c.header().minor, 5);
    // Calibration tables of several techniques, FULL first, three or four heights each.
    let calibration = c.calibration();
    assert_eq!(verify(&c).unwrap().calibration, calibration.len() as u64);
    let mut techniques: Vec<u32> = calibration.iter().map(|r| r.technique).collect();
    techniques.dedup();
    assert!(techniques.len() > 1 && techniques[0] == calibration_technique::FULL, "{techniques:?}");
    for t in &techniques {
        let samples = calibration.iter().filter(|r| r.technique == *t).count();
        assert!((3..=4).contains(&samples), "technique {t}: {samples} samples");
    }
    // Without CALIBRATION it is the 1.4 file, record for record, and the writer marks it 1.4.
    let v1_4 =
        ContainerData::from_container(&Container::open(golden_dir_of(4).join("every-kind-zstd.treelod")).unwrap());
    let mut data = ContainerData::from_container(&c);
    data.calibration.clear();
    assert!(data == v1_4, "v1_5 is v1_4 with a calibration");
    let bytes = data.to_bytes(Compression::None).unwrap();
    assert_eq!(Container::from_bytes(&bytes).unwrap().header().minor, 4);
}

#[test]
fn the_1_6_every_kind_file_has_a_bc7_atlas() {
    let c = Container::open(golden_dir_of(6).join("every-kind-zstd.treelod")).unwrap();
    assert_eq!(c.header().minor, 6);
    let v1_5 =
        ContainerData::from_container(&Container::open(golden_dir_of(5).join("every-kind-zstd.treelod")).unwrap());
    let data = ContainerData::from_container(&c);
    // The planes' atlas is BC7 (format 7), 8 x 4 with 4 levels: 2 + 1 + 1 + 1 blocks.
    let atlas = c.planes().iter().map(|p| p.image).find(|&i| c.images()[i as usize].format != image_format::LEAF_SLOTS);
    let atlas = atlas.or_else(|| c.billboards().first().map(|b| b.image)).unwrap() as usize;
    let record = c.images()[atlas];
    assert_eq!((record.format, record.width, record.height, record.data_length), (image_format::BC7_LINEAR, 8, 4, 80));
    // Decoded, it is the 1.5 file's RGBA8 atlas within BC7's error (random texels: a loose bound).
    let old = v1_5.images[atlas];
    let old_levels = treelod_format::image::decode_levels(&old, &v1_5.image_data[old.data_offset as usize..]).unwrap();
    let new_levels =
        treelod_format::image::decode_levels(&record, &data.image_data[record.data_offset as usize..]).unwrap();
    assert_eq!(old_levels.len(), new_levels.len());
    let (sum, n) = old_levels
        .iter()
        .flatten()
        .zip(new_levels.iter().flatten())
        .fold((0.0f64, 0usize), |(s, n), (a, b)| (s + f64::from(a.abs_diff(*b)).powi(2), n + 1));
    let rmse = (sum / n as f64).sqrt();
    assert!(rmse < 64.0, "RMSE {rmse:.1} of 255 on random texels");
    // Everything else is the 1.5 file's: the same records, the RGBA8 bytes still in IMAGE_DATA.
    let mut same = data.clone();
    same.images[atlas] = old;
    same.image_data.truncate(v1_5.image_data.len());
    assert!(same == v1_5, "v1_6 is v1_5 with the atlas as BC7");
    let bytes = same.to_bytes(Compression::None).unwrap();
    assert_eq!(Container::from_bytes(&bytes).unwrap().header().minor, 5);
}

#[test]
fn the_1_7_every_kind_file_has_every_kind_and_the_calibration_per_elevation() {
    let c = Container::open(golden_dir_of(7).join("every-kind-zstd.treelod")).unwrap();
    for kind in SectionKind::KNOWN {
        assert_eq!(c.section(kind).is_some(), kind.since_minor() <= 7, "{kind}");
    }
    assert_eq!(c.header().minor, 7);
    let report = verify(&c).unwrap();
    let per_elevation = c.calibration_elevations();
    assert_eq!(report.calibration_elevations, per_elevation.len() as u64);
    // The elevations 0, 30, 60 and 90 degrees, each with CALIBRATION's techniques at its heights,
    // the same primitives and an error of its own.
    let calibration = c.calibration();
    assert_eq!(per_elevation.len(), 4 * calibration.len());
    for (elevation, records) in [0.0, 30.0, 60.0, 90.0].into_iter().zip(per_elevation.chunks(calibration.len())) {
        for (r, mean) in records.iter().zip(calibration) {
            assert_eq!(
                (r.elevation, r.technique, r.height, r.primitives),
                (elevation, mean.technique, mean.height, mean.primitives)
            );
        }
    }
    assert!(per_elevation.iter().zip(calibration.iter().cycle()).any(|(r, mean)| r.error != mean.error));
    // Without CALIBRATION_ELEVATIONS it is the 1.6 file (1.5's kinds and a BC7 atlas), record for
    // record, and the writer marks it 1.6. The atlas's BC7 blocks are those of the build's encoder
    // of the day, so only their bytes may differ (same place, same length).
    let v1_6 =
        ContainerData::from_container(&Container::open(golden_dir_of(6).join("every-kind-zstd.treelod")).unwrap());
    let mut data = ContainerData::from_container(&c);
    data.calibration_elevations.clear();
    let bc7: Vec<_> = v1_6.images.iter().filter(|r| r.format == image_format::BC7_LINEAR).copied().collect();
    assert_eq!(bc7.len(), 1, "{:?}", v1_6.images);
    let blocks = bc7[0].data_offset as usize..(bc7[0].data_offset + bc7[0].data_length) as usize;
    assert_eq!(data.image_data.len(), v1_6.image_data.len());
    data.image_data[blocks.clone()].copy_from_slice(&v1_6.image_data[blocks]);
    assert!(data == v1_6, "v1_7 is v1_6 with the calibration per elevation");
    let bytes = data.to_bytes(Compression::None).unwrap();
    assert_eq!(Container::from_bytes(&bytes).unwrap().header().minor, 6);
}

#[test]
fn the_1_8_every_kind_file_has_every_kind_and_the_chain_levels_calibration() {
    let c = Container::open(golden_dir_of(8).join("every-kind-zstd.treelod")).unwrap();
    for kind in SectionKind::KNOWN {
        assert_eq!(c.section(kind).is_some(), kind.since_minor() <= 8, "{kind}");
    }
    assert_eq!(c.header().minor, 8);
    // Three samples per level of the chain, levels ascending from 0.
    let levels = c.chain_calibration();
    assert_eq!(verify(&c).unwrap().chain_calibration, levels.len() as u64);
    let mut numbers: Vec<u32> = levels.iter().map(|r| r.level).collect();
    numbers.dedup();
    assert_eq!(numbers, (0..numbers.len() as u32).collect::<Vec<_>>());
    assert!(!numbers.is_empty() && levels.len() == 3 * numbers.len(), "{levels:?}");
    // Without CHAIN_CALIBRATION it is the 1.7 file (1.6's kinds and the calibration per
    // elevation), record for record, and the writer marks it 1.7.
    let v1_7 =
        ContainerData::from_container(&Container::open(golden_dir_of(7).join("every-kind-zstd.treelod")).unwrap());
    let mut data = ContainerData::from_container(&c);
    data.chain_calibration.clear();
    assert!(data == v1_7, "v1_8 is v1_7 with the chain's per-level calibration");
    let bytes = data.to_bytes(Compression::None).unwrap();
    assert_eq!(Container::from_bytes(&bytes).unwrap().header().minor, 7);
}

#[test]
fn the_1_9_every_kind_file_has_every_kind_and_the_far_lines() {
    let c = Container::open(golden_dir_of(9).join("every-kind-zstd.treelod")).unwrap();
    for kind in SectionKind::KNOWN {
        assert_eq!(c.section(kind).is_some(), kind.since_minor() <= 9, "{kind}");
    }
    assert_eq!(c.header().minor, 9);
    // One hierarchy over copies of the cells' coarsest lines, merged across cells.
    let (far, lines) = (c.far_lines(), c.lines());
    let coarsest: Vec<_> = lines.iter().filter(|l| l.hi == f32::INFINITY).collect();
    let report = verify(&c).unwrap();
    assert_eq!((report.far_lines, report.far_line_leaves), (far.len() as u64, coarsest.len() as u64));
    assert!(coarsest.len() > 1 && far.len() > coarsest.len(), "{} far lines over {}", far.len(), coarsest.len());
    assert_eq!(c.far_line_ao().len(), far.len(), "FAR_LINE_AO, one byte per far line");
    // Far level 0 is the coarsest lines themselves, and it lasts half an octave past their largest
    // lo (the build's rule, more than the rule of the format).
    let geometry = |l: &LineRecord| (l.p0.map(f32::to_bits), l.r0.to_bits(), l.p1.map(f32::to_bits), l.r1.to_bits());
    let mut level_0: Vec<_> = far.iter().filter(|l| l.lo == 0.0).map(geometry).collect();
    let mut sources: Vec<_> = coarsest.iter().map(|l| geometry(l)).collect();
    level_0.sort_unstable();
    sources.sort_unstable();
    assert_eq!(level_0, sources);
    let largest_lo = coarsest.iter().map(|l| l.lo).fold(0.0, f32::max);
    assert!(far_threshold(far) >= std::f32::consts::SQRT_2 * largest_lo * (1.0 - 1e-6));
    assert!(far_switch(far) >= largest_lo, "at the switch the cells draw their coarsest lines");
    // Without FAR_LINES and FAR_LINE_AO it is the 1.8 file, record for record, and the writer marks
    // it 1.8: a 1.8 reader sees the same lines.
    let v1_8 =
        ContainerData::from_container(&Container::open(golden_dir_of(8).join("every-kind-zstd.treelod")).unwrap());
    let mut data = ContainerData::from_container(&c);
    data.far_lines.clear();
    data.far_line_ao.clear();
    assert!(data == v1_8, "v1_9 is v1_8 with the far lines");
    let bytes = data.to_bytes(Compression::None).unwrap();
    assert_eq!(Container::from_bytes(&bytes).unwrap().header().minor, 8);
}

#[test]
fn the_1_10_every_kind_file_has_every_kind_and_the_planes_diffuse_response() {
    let c = Container::open(golden_dir_of(10).join("every-kind-zstd.treelod")).unwrap();
    for kind in SectionKind::KNOWN {
        assert_eq!(c.section(kind).is_some(), kind.since_minor() <= 10, "{kind}");
    }
    assert_eq!(c.header().minor, 10);
    // One record per plane, in the planes' order, with values of their own (not all FLAT).
    let (diffuse, planes) = (c.plane_diffuse(), c.planes());
    assert_eq!(diffuse.len(), planes.len(), "PLANE_DIFFUSE, one record per plane");
    assert_eq!(verify(&c).unwrap().plane_diffuse, planes.len() as u64);
    assert!(diffuse.iter().any(|r| *r != PlaneDiffuseRecord::FLAT) && diffuse.windows(2).any(|w| w[0] != w[1]));
    // Without PLANE_DIFFUSE it is the 1.9 file, record for record, and the writer marks it 1.9: a
    // 1.9 reader sees the same planes, lit as FLAT.
    let v1_9 =
        ContainerData::from_container(&Container::open(golden_dir_of(9).join("every-kind-zstd.treelod")).unwrap());
    let mut data = ContainerData::from_container(&c);
    data.plane_diffuse.clear();
    assert!(data == v1_9, "v1_10 is v1_9 with the planes' diffuse records");
    let bytes = data.to_bytes(Compression::None).unwrap();
    assert_eq!(Container::from_bytes(&bytes).unwrap().header().minor, 9);
}

#[test]
fn the_1_11_every_kind_file_has_every_kind_and_the_octahedral_impostors() {
    let c = Container::open(golden_dir_of(11).join("every-kind-zstd.treelod")).unwrap();
    for kind in SectionKind::KNOWN {
        assert_eq!(c.section(kind).is_some(), kind.since_minor() <= 11, "{kind}");
    }
    assert_eq!(c.header().minor, 11);
    // One impostor per tree, in tree order, on the atlas the billboards sample (a colour image).
    let (octahedral, billboards) = (c.octahedral(), c.billboards());
    let trees: Vec<u32> = octahedral.iter().map(|o| o.tree).collect();
    assert_eq!(trees, (0..c.block().tree_count).collect::<Vec<_>>());
    assert!(octahedral.iter().all(|o| billboards.iter().any(|b| b.image == o.image)));
    assert!(octahedral.iter().all(|o| c.images()[o.image as usize].format == image_format::BC7_LINEAR));
    assert!(octahedral.iter().all(|o| (2..=64).contains(&o.frames) && o.radius > 0.0));
    assert!(octahedral.iter().all(|o| o.occlusion > 0.0 && o.occlusion < 1.0), "occlusion of their own");
    assert_eq!(verify(&c).unwrap().octahedral, u64::from(c.block().tree_count));
    // Without OCTAHEDRAL it is the 1.10 file, record for record, and the writer marks it 1.10: a
    // 1.10 reader sees the same trees, drawn with their other representations.
    let v1_10 =
        ContainerData::from_container(&Container::open(golden_dir_of(10).join("every-kind-zstd.treelod")).unwrap());
    let mut data = ContainerData::from_container(&c);
    data.octahedral.clear();
    assert!(data == v1_10, "v1_11 is v1_10 with the octahedral impostors");
    let bytes = data.to_bytes(Compression::None).unwrap();
    assert_eq!(Container::from_bytes(&bytes).unwrap().header().minor, 10);
}

#[test]
fn the_1_12_every_kind_file_has_every_kind_and_the_added_techniques_calibration() {
    let c = Container::open(golden_dir_of(12).join("every-kind-zstd.treelod")).unwrap();
    for kind in SectionKind::KNOWN {
        assert_eq!(c.section(kind).is_some(), kind.since_minor() <= 12, "{kind}");
    }
    assert_eq!(c.header().minor, 12);
    // The octahedral impostor's table: codes from FIRST_ADDED on, none of them in CALIBRATION.
    let (added, calibration) = (c.calibration_added(), c.calibration());
    assert!(!added.is_empty());
    assert!(
        added.iter().all(|r| (calibration_technique::FIRST_ADDED..calibration_technique::COUNT).contains(&r.technique))
    );
    assert!(added.iter().any(|r| r.technique == calibration_technique::OCTAHEDRAL));
    assert!(calibration.iter().all(|r| r.technique < calibration_technique::FIRST_ADDED));
    // At each elevation of CALIBRATION_ELEVATIONS, CALIBRATION_ADDED's techniques at its heights,
    // the same primitives and an error of its own.
    let per_elevation = c.calibration_elevations_added();
    assert_eq!(per_elevation.len(), 4 * added.len());
    for (elevation, records) in [0.0, 30.0, 60.0, 90.0].into_iter().zip(per_elevation.chunks(added.len())) {
        for (r, mean) in records.iter().zip(added) {
            assert_eq!(
                (r.elevation, r.technique, r.height, r.primitives),
                (elevation, mean.technique, mean.height, mean.primitives)
            );
        }
    }
    let mut elevations: Vec<f32> = c.calibration_elevations().iter().map(|r| r.elevation).collect();
    elevations.dedup();
    assert_eq!(elevations, [0.0, 30.0, 60.0, 90.0]);
    let report = verify(&c).unwrap();
    assert_eq!(
        (report.calibration_added, report.calibration_elevations_added),
        (added.len() as u64, per_elevation.len() as u64)
    );
    // Without CALIBRATION_ADDED and CALIBRATION_ELEVATIONS_ADDED it is the 1.11 file, record for
    // record, and the writer marks it 1.11: a 1.11 reader sees the same tables, without the
    // octahedral impostor's.
    is_the_previous_file_with(&c, 12, |data| {
        data.calibration_added.clear();
        data.calibration_elevations_added.clear();
    });
}

/// Asserts that `c`, the every-kind golden file of 1.`minor`, is that of 1.`minor − 1` record for
/// record once `without` removes what `minor` added, and that the writer then marks it
/// 1.`minor − 1`.
#[expect(clippy::unwrap_used, reason = "a test helper")]
fn is_the_previous_file_with(c: &Container, minor: u16, without: impl FnOnce(&mut ContainerData)) {
    let name = "every-kind-zstd.treelod";
    let previous = ContainerData::from_container(&Container::open(golden_dir_of(minor - 1).join(name)).unwrap());
    let mut data = ContainerData::from_container(c);
    without(&mut data);
    assert!(data == previous, "v1_{minor} is v1_{} with what {minor} adds", minor - 1);
    let bytes = data.to_bytes(Compression::None).unwrap();
    assert_eq!(Container::from_bytes(&bytes).unwrap().header().minor, minor - 1);
}

#[test]
fn the_1_13_every_kind_file_has_every_kind_and_the_octahedral_depth_planes() {
    let c = Container::open(golden_dir_of(13).join("every-kind-zstd.treelod")).unwrap();
    for kind in SectionKind::KNOWN.into_iter().filter(|k| k.since_minor() <= 13) {
        assert!(c.section(kind).is_some(), "{kind} missing");
    }
    assert_eq!(c.header().minor, 13);
    // A plane per view of each impostor, in their order: frames² each.
    let (octahedral, depth) = (c.octahedral(), c.octahedral_depth());
    let views: u32 = octahedral.iter().map(|o| o.frames * o.frames).sum();
    assert_eq!(depth.len(), views as usize);
    assert!(octahedral.len() >= 2 && octahedral.iter().any(|o| o.frames > 2), "grids of several sizes");
    let values = || depth.iter().flat_map(|p| [p.offset, p.slope_s, p.slope_t]);
    assert!(values().all(|v| (-1.0..=1.0).contains(&v)));
    assert!(depth.contains(&OctahedralDepthRecord::default()), "a view that shows nothing");
    assert!(depth.iter().any(|p| p.offset < 0.0) && depth.iter().any(|p| p.offset > 0.0));
    let report = verify(&c).unwrap();
    assert_eq!((report.octahedral, report.octahedral_depth), (octahedral.len() as u64, u64::from(views)));
    // Without OCTAHEDRAL_DEPTH it is the 1.12 file, record for record, and the writer marks it
    // 1.12: a 1.12 reader draws the same impostors, each view the plane through its centre.
    is_the_previous_file_with(&c, 13, |data| data.octahedral_depth.clear());
}

#[test]
fn the_1_14_every_kind_file_has_every_kind_and_the_points_facing() {
    let c = Container::open(golden_dir_of(14).join("every-kind-zstd.treelod")).unwrap();
    for kind in SectionKind::KNOWN {
        assert_eq!(c.section(kind).is_some(), kind.since_minor() <= 14, "{kind}");
    }
    assert_eq!(c.header().minor, 14);
    // A byte per point, of every kind: 0 (the mean coverage from every direction) to 255.
    let (points, facing) = (c.points(), c.point_facing());
    assert_eq!(facing.len(), points.len());
    assert!(facing.iter().any(|&f| f < 128) && facing.iter().any(|&f| f >= 128), "{facing:?}");
    assert_eq!(verify(&c).unwrap().point_facing, points.len() as u64);
    // Without POINT_FACING it is the 1.13 file, record for record, and the writer marks it 1.13:
    // a 1.13 reader draws the same points, each covering its mean share from every direction.
    is_the_previous_file_with(&c, 14, |data| data.point_facing.clear());
}

#[test]
fn the_1_15_every_kind_file_has_every_kind_and_the_octahedral_normals() {
    let c = Container::open(golden_dir_of(15).join("every-kind-zstd.treelod")).unwrap();
    for kind in SectionKind::KNOWN {
        assert_eq!(c.section(kind).is_some(), kind.since_minor() <= 15, "{kind}");
    }
    assert_eq!(c.header().minor, 15);
    // One normal grid per impostor, in their order, each of its colour grid's size inside the
    // image (unorm16 steps: at most 65536), and not where its colour grid starts.
    let (octahedral, normals) = (c.octahedral(), c.octahedral_normals());
    assert!(octahedral.len() >= 2, "{octahedral:?}");
    assert_eq!(normals.len(), octahedral.len());
    let corner = |uv: u32| (uv & 0xFFFF, uv >> 16);
    for (k, (o, n)) in octahedral.iter().zip(normals).enumerate() {
        let ((u0, v0), (u1, v1), (u, v)) = (corner(o.uv_min), corner(o.uv_max), corner(n.uv_min));
        assert!(u0 < u1 && v0 < v1, "impostor {k}: a colour grid of some size");
        assert!(u + (u1 - u0) <= 0x1_0000 && v + (v1 - v0) <= 0x1_0000, "impostor {k}: {n:?} of {o:?}");
        assert_ne!((u, v), (u0, v0), "impostor {k}: the normals lie elsewhere than the colours");
    }
    let report = verify(&c).unwrap();
    assert_eq!((report.octahedral, report.octahedral_normals), (octahedral.len() as u64, normals.len() as u64));
    // Without OCTAHEDRAL_NORMALS it is the 1.14 file, record for record, and the writer marks it
    // 1.14: a 1.14 reader draws the same impostors, each view lit as a whole.
    is_the_previous_file_with(&c, 15, |data| data.octahedral_normals.clear());
}

#[test]
fn the_1_16_every_kind_file_has_every_kind_and_the_octahedral_normal_grids() {
    let c = Container::open(golden_dir_of(16).join("every-kind-zstd.treelod")).unwrap();
    // Every kind of 1.16 but 1.15's OCTAHEDRAL_NORMALS, which OCTAHEDRAL_NORMAL_GRIDS replaces: a
    // file holds one of the two.
    for kind in SectionKind::KNOWN {
        let expected = kind != SectionKind::OCTAHEDRAL_NORMALS && kind.since_minor() <= 16;
        assert_eq!(c.section(kind).is_some(), expected, "{kind}");
    }
    assert_eq!(c.header().minor, 16);
    // One normal grid per impostor, in their order, each not empty, of half its colour grid's
    // size (unorm16 steps, rounded down), and not where its colour grid starts; the reader's
    // grid of each impostor is its record.
    let (octahedral, grids) = (c.octahedral(), c.octahedral_normal_grids());
    assert!(octahedral.len() >= 2, "{octahedral:?}");
    assert_eq!(grids.len(), octahedral.len());
    let corner = |uv: u32| (uv & 0xFFFF, uv >> 16);
    for (k, (o, g)) in octahedral.iter().zip(grids).enumerate() {
        let ((u0, v0), (u1, v1)) = (corner(o.uv_min), corner(o.uv_max));
        let ((a0, b0), (a1, b1)) = (corner(g.uv_min), corner(g.uv_max));
        assert!(u0 < u1 && v0 < v1, "impostor {k}: a colour grid of some size");
        assert!(a0 < a1 && b0 < b1, "impostor {k}: a normal grid of some size, {g:?}");
        assert_eq!((a1 - a0, b1 - b0), ((u1 - u0) / 2, (v1 - v0) / 2), "impostor {k}: half the size");
        assert_ne!((a0, b0), (u0, v0), "impostor {k}: the normals lie elsewhere than the colours");
        assert_eq!(c.octahedral_normal_grid(k), Some(*g), "impostor {k}");
    }
    assert_eq!(c.octahedral_normal_grid(octahedral.len()), None, "no such impostor");
    let report = verify(&c).unwrap();
    assert_eq!(
        (report.octahedral, report.octahedral_normals, report.octahedral_normal_grids),
        (octahedral.len() as u64, 0, grids.len() as u64)
    );
    // With 1.15's records at the grids' corners in place of the grids it is the 1.15 file, record
    // for record, and the writer marks it 1.15: the grids start where 1.15's did, only smaller.
    is_the_previous_file_with(&c, 16, |data| {
        data.octahedral_normals =
            data.octahedral_normal_grids.drain(..).map(|g| OctahedralNormalRecord { uv_min: g.uv_min }).collect();
    });
    // The 1.15 file's grids, read through the same accessor, are of the colour grids' size.
    let previous = Container::open(golden_dir_of(15).join("every-kind-zstd.treelod")).unwrap();
    for (k, (o, n)) in previous.octahedral().iter().zip(previous.octahedral_normals()).enumerate() {
        let g = previous.octahedral_normal_grid(k).expect("a grid per impostor");
        assert_eq!(g, n.grid(o), "impostor {k}");
        assert_eq!(g.uv_min, n.uv_min, "impostor {k}");
    }
}

#[test]
fn the_1_17_every_kind_file_has_every_kind_and_the_calibration_flip() {
    let c = Container::open(golden_dir_of(17).join("every-kind-zstd.treelod")).unwrap();
    // Every kind of 1.17 but 1.15's OCTAHEDRAL_NORMALS, which OCTAHEDRAL_NORMAL_GRIDS replaces: a
    // file holds one of the two.
    for kind in SectionKind::KNOWN {
        let expected = kind != SectionKind::OCTAHEDRAL_NORMALS && kind.since_minor() <= 17;
        assert_eq!(c.section(kind).is_some(), expected, "{kind}");
    }
    assert_eq!(c.header().minor, 17);
    // Rows over every view first, then at 30 and 90 degrees; at each, a base technique (full)
    // and an added one (octahedral), each at the same three heights, strictly increasing, with
    // FLIP errors in [0, 1].
    let flip = c.calibration_flip();
    assert_eq!(flip.len(), 3 * 2 * 3, "{flip:?}");
    let (full, octahedral) = (calibration_technique::FULL, calibration_technique::OCTAHEDRAL);
    let heights: Vec<f32> = flip[..3].iter().map(|r| r.height).collect();
    assert!(heights.windows(2).all(|w| w[0] < w[1]), "{heights:?}");
    let elevations = [FlipCalibrationRecord::EVERY_VIEW, 30.0, 90.0];
    for (k, r) in flip.iter().enumerate() {
        let (elevation, technique, height) = (elevations[k / 6], [full, octahedral][k / 3 % 2], heights[k % 3]);
        assert_eq!((r.elevation, r.technique, r.height), (elevation, technique, height), "record {k}");
        assert!((0.0..=1.0).contains(&r.flip), "record {k}: {r:?}");
    }
    assert_eq!(verify(&c).unwrap().calibration_flip, flip.len() as u64);
    // Without CALIBRATION_FLIP it is the 1.16 file, record for record, and the writer marks it
    // 1.16: a 1.16 reader sees the same tables and chooses by their RMSE alone.
    is_the_previous_file_with(&c, 17, |data| data.calibration_flip.clear());
}

#[test]
fn the_1_18_every_kind_file_has_every_kind_and_the_chain_calibration_flip() {
    let c = Container::open(golden_dir_of(18).join("every-kind-zstd.treelod")).unwrap();
    // Every kind but 1.15's OCTAHEDRAL_NORMALS, which OCTAHEDRAL_NORMAL_GRIDS replaces: a file
    // holds one of the two.
    for kind in SectionKind::KNOWN {
        assert_eq!(c.section(kind).is_some(), kind != SectionKind::OCTAHEDRAL_NORMALS, "{kind}");
    }
    assert_eq!(c.header().minor, 18);
    // A row at the level and height of each CHAIN_CALIBRATION record, in its order (levels from
    // 0, three heights each, strictly increasing), with FLIP errors in [0, 1] falling within a
    // level.
    let (chain, flip) = (c.chain_calibration(), c.chain_calibration_flip());
    assert_eq!(flip.len(), chain.len(), "{flip:?}");
    let mut levels: Vec<u32> = flip.iter().map(|r| r.level).collect();
    levels.dedup();
    assert_eq!(levels, [0, 1, 2], "three levels of the chain");
    assert_eq!(flip.len(), 3 * levels.len(), "{flip:?}");
    for (k, (r, m)) in flip.iter().zip(chain).enumerate() {
        assert_eq!((r.level, r.height), (m.level, m.height), "record {k}");
        assert!((0.0..=1.0).contains(&r.flip), "record {k}: {r:?}");
    }
    assert!(flip.windows(2).filter(|w| w[0].level == w[1].level).all(|w| w[0].flip > w[1].flip), "{flip:?}");
    assert_eq!(verify(&c).unwrap().chain_calibration_flip, flip.len() as u64);
    // Without CHAIN_CALIBRATION_FLIP it is the 1.17 file, record for record, and the writer marks
    // it 1.17: a 1.17 reader sees the same tables and picks the chain's level by its RMSE alone.
    is_the_previous_file_with(&c, 18, |data| data.chain_calibration_flip.clear());
}

/// The small 1.13 file: one octahedral impostor of 2 × 2 views and their four depth planes, view
/// `(i, j)` at `2j + i`, decoded to the values written out here.
#[test]
fn the_1_13_octahedral_depth_file_decodes_to_these_planes() {
    let path = golden_dir_of(13).join("octahedral-depth.treelod");
    let c = Container::open(&path).unwrap();
    assert_eq!(c.header().minor, 13);
    let [o] = c.octahedral() else { panic!("one impostor: {:?}", c.octahedral()) };
    assert_eq!((o.frames, o.tree, o.image), (2, 0, 0));
    let section = c.section(SectionKind::OCTAHEDRAL_DEPTH).unwrap();
    assert_eq!((section.entry.flags, section.entry.record_size, section.entry.raw_length), (0, 12, 48));
    let plane = |bits: [u32; 3]| {
        let [offset, slope_s, slope_t] = bits.map(f32::from_bits);
        OctahedralDepthRecord { offset, slope_s, slope_t }
    };
    // Views (0, 0), (1, 0), (0, 1), (1, 1).
    let expected = [
        plane([0xBE3E_F040, 0x3F2E_D857, 0xBD50_A150]),
        plane([0x3D87_A000, 0x3F3F_C5CF, 0x3DCF_92E8]),
        plane([0xBE30_E3C4, 0xBEB8_B2DD, 0x3F46_5701]),
        plane([0xBE6A_FB0C, 0x3E2A_B318, 0x3E94_2566]),
    ];
    assert_eq!(c.octahedral_depth(), expected);
    assert_eq!(expected[0].offset, -0.186_463_36);
    assert_eq!(expected[3].slope_t, 0.289_347_83);
    // Four distinct planes, none of them flat.
    for (a, p) in expected.iter().enumerate() {
        assert_ne!(*p, OctahedralDepthRecord::default());
        assert!(expected[a + 1..].iter().all(|q| q != p), "plane {a} is distinct");
    }
    assert_eq!(verify(&c).unwrap().octahedral_depth, 4);
    // Uncompressed, the writer writes it as it is.
    let bytes = std::fs::read(&path).unwrap();
    assert!(ContainerData::from_container(&c).to_bytes(Compression::None).unwrap() == bytes);
}

#[test]
fn the_extension_file_skips_its_unknown_kinds() {
    let c = open("extension.treelod");
    let kinds: Vec<u32> = c.sections().iter().map(|s| s.entry.kind).collect();
    assert_eq!(kinds, [0x01, 0x02, 0x03, 0x10, 0x11, 0x12, 0x13, 0x0100, 0x0001_0000]);
    let data = ContainerData::from_container(&c);
    let extra: Vec<(u32, usize)> = data.extra_sections.iter().map(|(k, b)| (*k, b.len())).collect();
    assert_eq!(extra, [(0x0100, 44), (0x0001_0000, 4)]);
    assert_eq!(data.triangles.len(), 2);
    assert_eq!(data.points.len(), 3);
}

/// The text between the spec's markers, without the newlines that frame it.
fn spec_example_in_spec() -> String {
    let spec = std::fs::read_to_string(spec_path()).expect("the spec is readable");
    let start = spec.find(SPEC_EXAMPLE_BEGIN).expect("the spec has the begin marker") + SPEC_EXAMPLE_BEGIN.len();
    let end = spec[start..].find(SPEC_EXAMPLE_END).expect("the spec has the end marker") + start;
    spec[start..end].trim_matches('\n').to_owned()
}

#[test]
fn spec_example_matches() {
    let bytes = std::fs::read(golden("minimal.treelod")).unwrap();
    let dump = spec_hex_dump(&bytes).unwrap();
    assert!(
        spec_example_in_spec() == dump.trim_matches('\n'),
        "format-spec/treelod.md §13.1 differs from `cargo run -p treelod-tests --bin spec-example`; paste its output \
         between the markers"
    );
    // Every byte of the file appears once in the dump.
    let hex_bytes: usize = dump
        .lines()
        .filter(|l| l.len() > 10 && l.as_bytes()[..8].iter().all(u8::is_ascii_hexdigit) && &l[8..10] == "  ")
        .map(|l| l[10..59].split_whitespace().count())
        .sum();
    assert_eq!(hex_bytes, bytes.len());
}

#[test]
fn the_spec_example_program_prints_the_spec_text() {
    let output = std::process::Command::new(env!("CARGO_BIN_EXE_spec-example")).output().unwrap();
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    assert_eq!(String::from_utf8(output.stdout).unwrap().trim_matches('\n'), spec_example_in_spec());
}

#[test]
fn make_golden_never_overwrites_a_file_without_force() {
    let dir = tempfile::tempdir().unwrap();
    let run = |args: &[&str]| {
        std::process::Command::new(env!("CARGO_BIN_EXE_make-golden")).args(args).arg(dir.path()).output().unwrap()
    };
    assert!(run(&[]).status.success());
    for recipe in golden_files() {
        let path = dir.path().join(format!("v1_{}", recipe.minor)).join(recipe.name);
        Container::open(&path).and_then(|c| verify(&c)).unwrap_or_else(|e| panic!("{}: {e}", recipe.name));
    }
    let again = run(&[]);
    assert!(again.status.success());
    assert!(String::from_utf8_lossy(&again.stdout).contains("unchanged"));

    let minimal = dir.path().join("v1_0").join("minimal.treelod");
    std::fs::write(&minimal, b"a golden file from another time").unwrap();
    let refused = run(&[]);
    assert!(!refused.status.success(), "a differing golden file is reported");
    assert!(String::from_utf8_lossy(&refused.stderr).contains("--force"));
    assert_eq!(std::fs::read(&minimal).unwrap(), b"a golden file from another time", "and kept");

    assert!(run(&["--force"]).status.success());
    Container::open(&minimal).unwrap();
}
