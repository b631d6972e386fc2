//! Where a buffer's or image's URI may point (docs/cli.md, "URIs"): relative references resolve
//! inside the model's directory. An absolute path, a `..` that climbs out of it, or a link inside
//! it that points out are refused unless external URIs are allowed, so a model in a library
//! cannot pull other files of the converting machine into its container. URIs with a scheme
//! (`http:`, `file:`) are never read; data URIs are handled by the caller.

use std::path::{Component, Path, PathBuf};

/// Why a URI is not read.
#[derive(Debug, PartialEq, Eq)]
pub(super) enum Refused {
    /// It points outside the model's directory.
    Outside,
    /// It has a scheme other than `data:`.
    Scheme,
}

/// The file `uri` (percent-encoded, relative to `dir`) names, if it may be read.
pub(super) fn resolve(uri: &str, dir: &Path, allow_external: bool) -> Result<PathBuf, Refused> {
    // A scheme is letters, digits, `+ - .` before the first `:`, the first letter a letter
    // (RFC 3986 §3.1); a one-letter one is a Windows drive (`C:`), an absolute path.
    if let Some((scheme, _)) = uri.split_once(':')
        && scheme.len() > 1
        && scheme.starts_with(|c: char| c.is_ascii_alphabetic())
        && scheme.chars().all(|c| c.is_ascii_alphanumeric() || "+-.".contains(c))
    {
        return Err(Refused::Scheme);
    }
    let decoded = super::percent_decode(uri);
    let relative = Path::new(&decoded);
    if allow_external {
        return Ok(dir.join(relative));
    }
    // Lexically: no root, no drive, and no `..` above the directory.
    let mut depth = 0usize;
    for component in relative.components() {
        match component {
            Component::Normal(_) => depth += 1,
            Component::CurDir => {}
            Component::ParentDir => depth = depth.checked_sub(1).ok_or(Refused::Outside)?,
            Component::RootDir | Component::Prefix(_) => return Err(Refused::Outside),
        }
    }
    let file = dir.join(relative);
    // Through links: the file as the system finds it must lie in the directory as it finds it. A
    // file that does not exist is left to the read, which reports it missing.
    if let (Ok(real_dir), Ok(real_file)) = (dir.canonicalize(), file.canonicalize())
        && !real_file.starts_with(&real_dir)
    {
        return Err(Refused::Outside);
    }
    Ok(file)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn relative_uris_inside_the_directory_resolve() {
        let dir = Path::new("/models/oak");
        assert_eq!(resolve("tree.bin", dir, false), Ok(dir.join("tree.bin")));
        assert_eq!(resolve("tex/../tree%20a.bin", dir, false), Ok(dir.join("tex/../tree a.bin")));
        assert_eq!(resolve("./a/b.png", dir, false), Ok(dir.join("./a/b.png")));
    }

    #[test]
    fn uris_leaving_the_directory_are_refused_unless_allowed() {
        let dir = Path::new("/models/oak");
        for uri in ["../secret.bin", "a/../../secret.bin", "/etc/passwd", "%2Fetc%2Fpasswd", "..%2Fsecret.bin"] {
            assert_eq!(resolve(uri, dir, false), Err(Refused::Outside), "{uri}");
            assert!(resolve(uri, dir, true).is_ok(), "{uri}");
        }
    }

    #[test]
    fn uris_with_a_scheme_are_never_files() {
        let dir = Path::new("/models/oak");
        for uri in ["http://example.com/a.bin", "file:///etc/passwd", "https:a.bin"] {
            assert_eq!(resolve(uri, dir, true), Err(Refused::Scheme), "{uri}");
        }
    }

    #[cfg(unix)]
    #[test]
    fn a_link_pointing_out_is_refused() {
        let root = tempfile::tempdir().expect("temporary directory");
        let model = root.path().join("model");
        std::fs::create_dir(&model).expect("model directory");
        std::fs::write(root.path().join("secret.bin"), b"secret").expect("secret file");
        std::os::unix::fs::symlink(root.path().join("secret.bin"), model.join("tree.bin")).expect("link");
        std::fs::write(model.join("own.bin"), b"own").expect("own file");
        assert_eq!(resolve("tree.bin", &model, false), Err(Refused::Outside));
        assert_eq!(resolve("own.bin", &model, false), Ok(model.join("own.bin")));
        assert_eq!(resolve("tree.bin", &model, true), Ok(model.join("tree.bin")));
    }
}
