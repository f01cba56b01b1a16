//! What a link looks like: its URDF `<visual>` elements (primitives and meshes with their colour),
//! for viewers; the physics never reads them.

use std::path::{Path, PathBuf};

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

/// Colour of a visual without a material (light grey).
pub const DEFAULT_RGBA: [f64; 4] = [0.7, 0.7, 0.72, 1.0];

/// The geometry of one visual; sizes are full extents and lengths as in URDF.
#[derive(Debug, Clone, PartialEq)]
pub enum VisualGeometry {
    Box {
        size: Vector3<f64>,
    },
    Sphere {
        radius: f64,
    },
    Cylinder {
        radius: f64,
        length: f64,
    },
    Capsule {
        radius: f64,
        length: f64,
    },
    /// A mesh file: its name in the URDF, the file it resolves to (None when it cannot be found:
    /// a viewer then leaves it out) and its per-axis scale.
    Mesh {
        filename: String,
        path: Option<PathBuf>,
        scale: [f64; 3],
    },
}

/// One `<visual>` of a link: geometry, pose in the link frame and RGBA colour in [0, 1].
#[derive(Debug, Clone, PartialEq)]
pub struct Visual {
    pub geometry: VisualGeometry,
    pub origin: Isometry3<f64>,
    pub rgba: [f64; 4],
}

fn colour(material: Option<&urdf_rs::Material>, named: &[urdf_rs::Material]) -> [f64; 4] {
    let Some(material) = material else { return DEFAULT_RGBA };
    let color = material
        .color
        .as_ref()
        .or_else(|| named.iter().find(|m| m.name == material.name).and_then(|m| m.color.as_ref()));
    match color {
        Some(c) if c.rgba.iter().all(|v| v.is_finite()) => [c.rgba[0], c.rgba[1], c.rgba[2], c.rgba[3]],
        _ => DEFAULT_RGBA,
    }
}

/// The visuals of a URDF link; `source` is the URDF's path or name (meshes resolve against its
/// directory when it is a file). Visuals with non-finite numbers are left out: a viewer cannot draw
/// them, and the model does not need them.
pub fn convert(source: &str, link: &urdf_rs::Link, materials: &[urdf_rs::Material]) -> Vec<Visual> {
    let urdf_dir = Path::new(source).is_file().then(|| Path::new(source).parent()).flatten();
    let mut out = Vec::new();
    for visual in &link.visual {
        let (xyz, rpy) = (visual.origin.xyz, visual.origin.rpy);
        if !xyz.iter().chain(rpy.iter()).all(|v| v.is_finite()) {
            continue;
        }
        let geometry = match &visual.geometry {
            urdf_rs::Geometry::Box { size } => VisualGeometry::Box {
                size: Vector3::new(size[0], size[1], size[2]),
            },
            urdf_rs::Geometry::Sphere { radius } => VisualGeometry::Sphere { radius: *radius },
            urdf_rs::Geometry::Cylinder { radius, length } => VisualGeometry::Cylinder {
                radius: *radius,
                length: *length,
            },
            urdf_rs::Geometry::Capsule { radius, length } => VisualGeometry::Capsule {
                radius: *radius,
                length: *length,
            },
            urdf_rs::Geometry::Mesh { filename, scale } => VisualGeometry::Mesh {
                filename: filename.clone(),
                path: super::mesh::resolve(filename, urdf_dir).ok(),
                scale: scale.as_ref().map_or([1.0; 3], |s| [s[0], s[1], s[2]]),
            },
        };
        let sizes_finite = match &geometry {
            VisualGeometry::Box { size } => size.iter().all(|v| v.is_finite()),
            VisualGeometry::Sphere { radius } => radius.is_finite(),
            VisualGeometry::Cylinder { radius, length } | VisualGeometry::Capsule { radius, length } => {
                radius.is_finite() && length.is_finite()
            }
            VisualGeometry::Mesh { scale, .. } => scale.iter().all(|v| v.is_finite()),
        };
        if !sizes_finite {
            continue;
        }
        out.push(Visual {
            geometry,
            origin: Isometry3::from_parts(
                Translation3::new(xyz[0], xyz[1], xyz[2]),
                UnitQuaternion::from_euler_angles(rpy[0], rpy[1], rpy[2]),
            ),
            rgba: colour(visual.material.as_ref(), materials),
        });
    }
    out
}
