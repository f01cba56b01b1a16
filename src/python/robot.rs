//! The robot's roles and looks at the boundary: scene options in (tool, held joints, base,
//! postures), roles and visuals out, and mesh triangles for viewers.

use std::path::PathBuf;

use pyo3::prelude::*;

use super::convert::matrix_entries;
use super::error::run;
use crate::error::{Result, SabreError};
use crate::model::kinematics::KinematicTree;
use crate::model::roles::{BaseDecl, RoleDecls, ToolSource, ToolSpec};
use crate::model::scene::{builtin, Scene, BUILTIN_OBJECTS, BUILTIN_ROBOTS};
use crate::model::urdf::{load_urdf_file, parse_urdf, ParsedUrdf};
use crate::model::visual::VisualGeometry;

/// A tool as Python hands it over: (parent link, source kind "builtin" | "file" | "text", the
/// tool's name, path or URDF text, xyz, rpy, control frame or None).
pub(crate) type ToolRow = (String, String, String, [f64; 3], [f64; 3], Option<String>);

/// A base as Python hands it over: ("planar" | "fixed", joints (x, y, yaw) or empty, link or None).
type BaseRow = (String, Vec<String>, Option<String>);

/// The scene options of the robot (see `sabre.Scene.from_urdf`), one dict entry each.
#[derive(FromPyObject)]
#[pyo3(from_item_all)]
pub(crate) struct RobotOptions {
    tool: Option<ToolRow>,
    tool_frame: Option<String>,
    hold: Vec<(String, f64)>,
    base: Option<BaseRow>,
    home: Vec<(String, f64)>,
    start: Vec<(String, f64)>,
    work: Vec<(String, f64)>,
    wrist_sensor: Option<String>,
}

fn tool_spec(row: ToolRow) -> Result<ToolSpec> {
    let (parent, kind, value, xyz, rpy, frame) = row;
    let source = match kind.as_str() {
        "builtin" => ToolSource::Builtin(value),
        "file" => ToolSource::File(PathBuf::from(value)),
        "text" => ToolSource::Text {
            name: "tool".into(),
            text: value,
        },
        other => return Err(SabreError::invalid("tool", format!("unknown source kind '{other}'"))),
    };
    if !xyz.iter().chain(&rpy).all(|v| v.is_finite()) {
        return Err(SabreError::invalid("tool", "xyz and rpy must be finite"));
    }
    Ok(ToolSpec {
        parent,
        source,
        xyz,
        rpy,
        frame,
    })
}

impl RobotOptions {
    pub(crate) fn decls(self) -> Result<RoleDecls> {
        let base = match self.base {
            None => None,
            Some((kind, joints, link)) if kind == "planar" => Some(BaseDecl::Planar {
                joints: joints
                    .try_into()
                    .map_err(|_| SabreError::invalid("base", "a planar base needs three joints (x, y, yaw)"))?,
                link,
            }),
            Some((kind, _, link)) if kind == "fixed" => Some(BaseDecl::Fixed { link }),
            Some((kind, _, _)) => return Err(SabreError::invalid("base", format!("unknown base kind '{kind}'"))),
        };
        for (name, value) in self.hold.iter().chain(&self.home).chain(&self.start).chain(&self.work) {
            if !value.is_finite() {
                return Err(SabreError::invalid(
                    format!("joint '{name}'"),
                    format!("value {value} is not finite"),
                ));
            }
        }
        Ok(RoleDecls {
            tool: self.tool.map(tool_spec).transpose()?,
            tool_frame: self.tool_frame,
            hold: self.hold,
            base,
            home: self.home,
            start: self.start,
            work: self.work,
            wrist_sensor: self.wrist_sensor,
        })
    }
}

/// A URDF by kind: "builtin" (a robot or object compiled into the library, by name), "file" (a
/// path) or "text"; `robot` says which table a built-in name is looked up in.
pub(crate) fn parsed(kind: &str, value: &str, robot: bool) -> Result<ParsedUrdf> {
    match kind {
        "builtin" => {
            let table = if robot { BUILTIN_ROBOTS } else { BUILTIN_OBJECTS };
            parse_urdf(value, builtin(if robot { "robot" } else { "object" }, table, value)?)
        }
        "file" => load_urdf_file(std::path::Path::new(value)),
        "text" => parse_urdf(if robot { "robot" } else { "object" }, value),
        other => Err(SabreError::invalid("URDF source", format!("unknown kind '{other}'"))),
    }
}

/// One visual: (link, kind, size, pose row-major, rgba, mesh file or None, mesh scale). Kinds and
/// sizes: "box" (extents), "sphere" (radius), "cylinder" and "capsule" (radius, length), "mesh"
/// (empty; the file and scale say it).
pub(crate) type VisualRow = (String, String, Vec<f64>, [f64; 16], [f64; 4], Option<String>, [f64; 3]);

pub(crate) fn visual_rows(tree: &KinematicTree) -> Vec<VisualRow> {
    let mut out = Vec::new();
    for link in &tree.links {
        for v in &link.visuals {
            let (kind, size, file, scale) = match &v.geometry {
                VisualGeometry::Box { size } => ("box", vec![size.x, size.y, size.z], None, [1.0; 3]),
                VisualGeometry::Sphere { radius } => ("sphere", vec![*radius], None, [1.0; 3]),
                VisualGeometry::Cylinder { radius, length } => ("cylinder", vec![*radius, *length], None, [1.0; 3]),
                VisualGeometry::Capsule { radius, length } => ("capsule", vec![*radius, *length], None, [1.0; 3]),
                VisualGeometry::Mesh { path, scale, .. } => {
                    ("mesh", vec![], path.as_ref().map(|p| p.display().to_string()), *scale)
                }
            };
            out.push((
                link.name.clone(),
                kind.into(),
                size,
                matrix_entries(&v.origin),
                v.rgba,
                file,
                scale,
            ));
        }
    }
    out
}

/// The roles of a scene's robot: (tool frame or None, base q indices (x, y, yaw) or None, base
/// link, held joints, wrist-sensor link, how each role was found as (role, how) pairs, the attached
/// tool as a [`ToolRow`] or None).
pub(crate) type RolesRow = (
    Option<String>,
    Option<[usize; 3]>,
    String,
    Vec<(String, f64)>,
    String,
    Vec<(String, String)>,
    Option<ToolRow>,
);

pub(crate) fn roles_row(scene: &Scene) -> RolesRow {
    let roles = &scene.roles;
    let name = |l: usize| scene.robot.links[l].name.clone();
    let mut origins = vec![
        ("tool_frame".to_string(), roles.origins.tool_frame.to_string()),
        ("base".to_string(), roles.origins.base.to_string()),
        ("wrist_sensor".to_string(), roles.origins.wrist_sensor.to_string()),
        ("geometry".to_string(), scene.geometry_origin.0.to_string()),
    ];
    for ((joint, _), how) in roles.held.iter().zip(&roles.origins.held) {
        origins.push((format!("hold:{joint}"), how.to_string()));
    }
    let tool = roles.tool.as_ref().map(|t| {
        let (kind, value) = match &t.source {
            ToolSource::Builtin(n) => ("builtin", n.clone()),
            ToolSource::File(p) => ("file", p.display().to_string()),
            ToolSource::Text { text, .. } => ("text", text.clone()),
        };
        (t.parent.clone(), kind.to_string(), value, t.xyz, t.rpy, t.frame.clone())
    });
    (
        roles.tool_frame.map(name),
        roles.base.map(|b| b.indices()),
        name(roles.base_link),
        roles.held.clone(),
        name(roles.wrist_sensor),
        origins,
        tool,
    )
}

/// The triangles of a mesh file (STL, OBJ or COLLADA) scaled per axis: (vertices (V, 3), faces (F, 3)).
#[pyfunction]
pub(crate) fn mesh_triangles(path: PathBuf, scale: [f64; 3]) -> PyResult<crate::model::mesh::Triangles> {
    run(|| crate::model::mesh::load_triangles(&path, scale).map_err(|e| SabreError::urdf(path.display().to_string(), e)))
}
