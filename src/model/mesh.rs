//! Mesh geometry: URDF `<mesh>` files (STL, OBJ, COLLADA) found on a search path and reduced to
//! convex hulls, which are cached on disk, or read as triangles for viewers.
//!
//! A filename resolves as: an absolute path; `package://<pkg>/<rest>` under each directory of
//! `SABRE_PACKAGE_PATH` and `ROS_PACKAGE_PATH` (as `<dir>/<pkg>/<rest>`) and of
//! `AMENT_PREFIX_PATH` (as `<prefix>/share/<pkg>/<rest>`), then, as ROS tools find a package from
//! inside it, in the nearest folder above the URDF file that is named `<pkg>` or holds a
//! `package.xml` whose `<name>` is `<pkg>`; a relative path against the URDF file's directory, then
//! each directory of `SABRE_MESH_PATH`, then the working directory. `file://` prefixes are
//! dropped. An STL file is one convex piece; an OBJ file one per object (`o`) or group (`g`) it
//! holds, as convex decompositions are written. Hulls are cached in `$SABRE_CACHE_DIR`, else
//! `$XDG_CACHE_HOME/sabre/hulls`, else `~/.cache/sabre/hulls`, keyed by the file's bytes and scale.

use std::hash::{Hash, Hasher};
use std::path::{Path, PathBuf};

use nalgebra::Point3;

/// Most vertices a mesh file may have: beyond it a collision hull is not what the file is for.
pub const MAX_MESH_VERTICES: usize = 2_000_000;

fn split_paths(var: &str) -> Vec<PathBuf> {
    std::env::var_os(var)
        .map(|v| std::env::split_paths(&v).collect())
        .unwrap_or_default()
}

/// The `<name>` of the package whose `package.xml` is at `path`, if it reads as one.
fn package_xml_name(path: &Path) -> Option<String> {
    let text = std::fs::read_to_string(path).ok()?;
    let doc = roxmltree::Document::parse(&text).ok()?;
    let name = doc.root_element().children().find(|n| n.has_tag_name("name"))?;
    Some(name.text()?.trim().to_string())
}

/// The nearest folder at or above `start` that is the package `package`: named like it, or holding
/// a `package.xml` that names it.
fn package_above(start: &Path, package: &str) -> Option<PathBuf> {
    let start = start.canonicalize().unwrap_or_else(|_| start.to_path_buf());
    start
        .ancestors()
        .find(|dir| {
            dir.file_name().is_some_and(|n| n == package)
                || package_xml_name(&dir.join("package.xml")).is_some_and(|n| n == package)
        })
        .map(Path::to_path_buf)
}

/// The file a URDF mesh `filename` names, or a message listing where it was looked for.
pub fn resolve(filename: &str, urdf_dir: Option<&Path>) -> std::result::Result<PathBuf, String> {
    let name = filename.strip_prefix("file://").unwrap_or(filename);
    let mut tried = Vec::new();
    let mut walked = None;
    if let Some(rest) = name.strip_prefix("package://") {
        let (package, relative) = rest
            .split_once('/')
            .ok_or_else(|| format!("'{filename}' names no file in its package"))?;
        let roots = split_paths("SABRE_PACKAGE_PATH")
            .into_iter()
            .chain(split_paths("ROS_PACKAGE_PATH"));
        let shares = split_paths("AMENT_PREFIX_PATH").into_iter().map(|p| p.join("share"));
        for dir in roots.chain(shares) {
            tried.push(dir.join(package).join(relative));
        }
        if let Some(dir) = urdf_dir {
            match package_above(dir, package) {
                Some(root) => tried.push(root.join(relative)),
                None => {
                    walked = Some(format!(
                        "no folder at or above {} is named '{package}' or has a package.xml naming it",
                        dir.display()
                    ))
                }
            }
        }
    } else if Path::new(name).is_absolute() {
        tried.push(PathBuf::from(name));
    } else {
        let dirs = urdf_dir
            .map(Path::to_path_buf)
            .into_iter()
            .chain(split_paths("SABRE_MESH_PATH"));
        for dir in dirs.chain(std::env::current_dir().ok()) {
            tried.push(dir.join(name));
        }
    }
    tried.iter().find(|p| p.is_file()).cloned().ok_or_else(|| {
        let mut places: Vec<String> = tried.iter().map(|p| p.display().to_string()).collect();
        places.extend(walked);
        format!(
            "mesh '{filename}' not found (looked in: {}; set SABRE_MESH_PATH or SABRE_PACKAGE_PATH)",
            if places.is_empty() {
                "nowhere: no package path is set".to_string()
            } else {
                places.join("; ")
            }
        )
    })
}

/// The vertices of each convex piece of the mesh file at `path`: all of an STL's or a COLLADA
/// document's, each OBJ object's or group's own.
fn read_pieces(path: &Path, bytes: &[u8]) -> std::result::Result<Vec<Vec<[f64; 3]>>, String> {
    let extension = path.extension().and_then(|e| e.to_str()).unwrap_or("").to_ascii_lowercase();
    match extension.as_str() {
        "stl" => {
            let mesh = stl_io::read_stl(&mut std::io::Cursor::new(bytes)).map_err(|e| format!("cannot read STL: {e}"))?;
            Ok(vec![mesh
                .vertices
                .iter()
                .map(|v| [f64::from(v[0]), f64::from(v[1]), f64::from(v[2])])
                .collect()])
        }
        "obj" => {
            let options = tobj::LoadOptions {
                triangulate: false,
                single_index: false,
                ..Default::default()
            };
            let (models, _) = tobj::load_obj_buf(&mut std::io::Cursor::new(bytes), &options, |_| {
                Ok((Vec::new(), Default::default()))
            })
            .map_err(|e| format!("cannot read OBJ: {e}"))?;
            Ok(models
                .iter()
                .map(|m| {
                    m.mesh
                        .positions
                        .chunks_exact(3)
                        .map(|p| [f64::from(p[0]), f64::from(p[1]), f64::from(p[2])])
                        .collect()
                })
                .collect())
        }
        // one hull, as for an STL: a description's visual parts are pieces of a surface, not convex solids
        "dae" => Ok(vec![read_collada(bytes)?.0]),
        other => Err(format!("mesh format '.{other}' is not supported (STL, OBJ and COLLADA are)")),
    }
}

/// A triangle mesh as vertices and vertex-index triples.
pub type Triangles = (Vec<[f64; 3]>, Vec<[u32; 3]>);

/// The vertices and triangles of a COLLADA document, each geometry placed by the transforms of the
/// scene nodes that instance it and scaled by the document's `<unit meter>`.
fn read_collada(bytes: &[u8]) -> std::result::Result<Triangles, String> {
    let scene = mesh_loader::collada::from_slice(bytes).map_err(|e| format!("cannot read COLLADA: {e}"))?;
    let mut vertices = Vec::new();
    let mut faces = Vec::new();
    for mesh in &scene.meshes {
        let offset = vertices.len() as u32;
        vertices.extend(mesh.vertices.iter().map(|v| v.map(f64::from)));
        faces.extend(mesh.faces.iter().map(|f| f.map(|i| i + offset)));
    }
    Ok((vertices, faces))
}

/// The triangles of the mesh at `path` (STL, OBJ or COLLADA), scaled per axis, as vertices and
/// vertex-index triples: what a viewer draws.
pub fn load_triangles(path: &Path, scale: [f64; 3]) -> std::result::Result<Triangles, String> {
    let bytes = std::fs::read(path).map_err(|e| format!("cannot read mesh {}: {e}", path.display()))?;
    let extension = path.extension().and_then(|e| e.to_str()).unwrap_or("").to_ascii_lowercase();
    let (vertices, faces) = match extension.as_str() {
        "dae" => read_collada(&bytes)?,
        "stl" => {
            let mesh = stl_io::read_stl(&mut std::io::Cursor::new(&bytes)).map_err(|e| format!("cannot read STL: {e}"))?;
            let vertices = mesh.vertices.iter().map(|v| [v[0], v[1], v[2]].map(f64::from)).collect();
            let faces = mesh.faces.iter().map(|f| f.vertices.map(|i| i as u32)).collect();
            (vertices, faces)
        }
        "obj" => {
            let options = tobj::LoadOptions {
                triangulate: true,
                single_index: true,
                ..Default::default()
            };
            let (models, _) = tobj::load_obj_buf(&mut std::io::Cursor::new(&bytes), &options, |_| {
                Ok((Vec::new(), Default::default()))
            })
            .map_err(|e| format!("cannot read OBJ: {e}"))?;
            let (mut vertices, mut faces) = (Vec::new(), Vec::new());
            for m in &models {
                let offset = vertices.len() as u32;
                vertices.extend(m.mesh.positions.chunks_exact(3).map(|p| [p[0], p[1], p[2]].map(f64::from)));
                faces.extend(
                    m.mesh
                        .indices
                        .chunks_exact(3)
                        .map(|t| [t[0] + offset, t[1] + offset, t[2] + offset]),
                );
            }
            (vertices, faces)
        }
        other => return Err(format!("mesh format '.{other}' is not supported (STL, OBJ and COLLADA are)")),
    };
    if vertices.len() > MAX_MESH_VERTICES || faces.iter().flatten().any(|&i| i as usize >= vertices.len()) {
        return Err(format!(
            "mesh {} is too large or its faces name missing vertices",
            path.display()
        ));
    }
    let scaled = vertices
        .iter()
        .map(|v| [v[0] * scale[0], v[1] * scale[1], v[2] * scale[2]])
        .collect();
    Ok((scaled, faces))
}

fn cache_dir() -> Option<PathBuf> {
    if let Some(dir) = std::env::var_os("SABRE_CACHE_DIR") {
        return Some(PathBuf::from(dir));
    }
    let base = std::env::var_os("XDG_CACHE_HOME")
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".cache")))?;
    Some(base.join("sabre").join("hulls"))
}

fn cache_file(bytes: &[u8], scale: &[f64; 3]) -> Option<PathBuf> {
    let mut hasher = std::collections::hash_map::DefaultHasher::new();
    bytes.hash(&mut hasher);
    scale.iter().for_each(|s| s.to_bits().hash(&mut hasher));
    env!("CARGO_PKG_VERSION").hash(&mut hasher);
    "convex pieces".hash(&mut hasher); // the file format: pieces separated by blank lines
    Some(cache_dir()?.join(format!("{:016x}.hull", hasher.finish())))
}

/// The hulls of a cache file: one per block of lines, blocks separated by a blank line.
fn read_cache(path: &Path) -> Option<Vec<Vec<Point3<f64>>>> {
    let text = std::fs::read_to_string(path).ok()?;
    let pieces: Option<Vec<Vec<Point3<f64>>>> = text
        .split("\n\n")
        .filter(|block| !block.trim().is_empty())
        .map(|block| {
            block
                .lines()
                .map(|line| {
                    let v: Vec<f64> = line.split_whitespace().filter_map(|t| t.parse().ok()).collect();
                    (v.len() == 3 && v.iter().all(|x| x.is_finite())).then(|| Point3::new(v[0], v[1], v[2]))
                })
                .collect::<Option<Vec<_>>>()
                .filter(|p| p.len() >= 4)
        })
        .collect();
    pieces.filter(|p| !p.is_empty())
}

/// The convex hull of one piece's vertices, or why it has none (too few points, no volume).
fn hull_of(vertices: &[[f64; 3]], scale: [f64; 3]) -> std::result::Result<Vec<Point3<f64>>, String> {
    let points: Vec<_> = vertices
        .iter()
        .map(|v| rapier3d_f64::parry::math::Vector::new(v[0] * scale[0], v[1] * scale[1], v[2] * scale[2]))
        .collect();
    if points.len() < 4
        || points
            .iter()
            .any(|p| !(p.x.is_finite() && p.y.is_finite() && p.z.is_finite()))
    {
        return Err("fewer than 4 vertices or non-finite ones".to_string());
    }
    let (hull, faces) = rapier3d_f64::parry::transformation::convex_hull(&points);
    let volume: f64 = faces
        .iter()
        .map(|f| {
            let [a, b, c] = f.map(|i| hull[i as usize]);
            a.dot(b.cross(c)) / 6.0
        })
        .sum();
    let extent = hull.iter().map(|p| p.length()).fold(0.0, f64::max);
    if hull.len() < 4 || volume.abs() <= 1e-9 * extent.powi(3) {
        return Err("flat: its convex hull has no volume".to_string());
    }
    Ok(hull.iter().map(|p| Point3::new(p.x, p.y, p.z)).collect())
}

/// The convex hulls' vertices of the pieces of the mesh at `path`, scaled per axis (from the cache
/// when the same file and scale were hulled before). A piece without volume is left out when
/// others have one (a decal or a stray quad in an OBJ); a file without any is refused.
pub fn load_hulls(path: &Path, scale: [f64; 3]) -> std::result::Result<Vec<Vec<Point3<f64>>>, String> {
    let bytes = std::fs::read(path).map_err(|e| format!("cannot read mesh {}: {e}", path.display()))?;
    let cached = cache_file(&bytes, &scale);
    if let Some(hulls) = cached.as_deref().and_then(read_cache) {
        return Ok(hulls);
    }
    let pieces = read_pieces(path, &bytes)?;
    let vertices: usize = pieces.iter().map(Vec::len).sum();
    if vertices > MAX_MESH_VERTICES {
        return Err(format!(
            "mesh {} has {vertices} vertices (at most {MAX_MESH_VERTICES})",
            path.display()
        ));
    }
    let results: Vec<_> = pieces.iter().map(|piece| hull_of(piece, scale)).collect();
    let hulls: Vec<Vec<Point3<f64>>> = results.iter().filter_map(|r| r.as_ref().ok().cloned()).collect();
    if hulls.is_empty() {
        let why = results
            .into_iter()
            .find_map(|r| r.err())
            .unwrap_or_else(|| "no vertices".to_string());
        let why = if why.starts_with("flat") {
            format!("is {why}")
        } else {
            format!("has {why}")
        };
        return Err(format!("mesh {} {why}", path.display()));
    }
    if let Some(file) = cached {
        let text: Vec<String> = hulls
            .iter()
            .map(|hull| hull.iter().map(|p| format!("{:e} {:e} {:e}\n", p.x, p.y, p.z)).collect())
            .collect();
        // Written aside and renamed, so that another process never reads half a file; a cache that
        // cannot be written is only slower: the hulls are returned either way.
        let partial = file.with_extension(format!("part{}", std::process::id()));
        let _ = std::fs::create_dir_all(file.parent().unwrap_or(Path::new(".")))
            .and_then(|()| std::fs::write(&partial, text.join("\n")))
            .and_then(|()| std::fs::rename(&partial, &file));
    }
    Ok(hulls)
}
