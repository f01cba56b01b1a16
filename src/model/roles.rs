//! What a robot's parts are for, as declared: the tool to attach and its control frame, held joints,
//! the base, the home, start and working postures and the wrist sensor's link, from the `<sabre>` block of
//! a robot URDF or from the scene's options (which win).

use std::path::PathBuf;

use nalgebra::{Isometry3, Translation3, UnitQuaternion};

use crate::error::{Result, SabreError};

/// Tools compiled into the library, by name: URDF fragments whose root link is fixed to a robot link.
pub const BUILTIN_TOOLS: &[(&str, &str)] = &[("hook", include_str!("../../assets/tools/hook.urdf"))];

/// Where a tool's URDF fragment comes from.
#[derive(Debug, Clone, PartialEq)]
pub enum ToolSource {
    /// One of [`BUILTIN_TOOLS`].
    Builtin(String),
    /// A file (relative paths against the robot URDF's directory).
    File(PathBuf),
    /// URDF text, named `name` in messages.
    Text { name: String, text: String },
}

/// A tool fixed to robot link `parent` at `xyz`, `rpy` (URDF conventions); `frame` names the
/// control frame it defines (default: the fragment's own `<sabre><tool_frame>`).
#[derive(Debug, Clone, PartialEq)]
pub struct ToolSpec {
    pub parent: String,
    pub source: ToolSource,
    pub xyz: [f64; 3],
    pub rpy: [f64; 3],
    pub frame: Option<String>,
}

impl ToolSpec {
    /// Pose of the tool's root link in the parent link's frame.
    pub fn origin(&self) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::new(self.xyz[0], self.xyz[1], self.xyz[2]),
            UnitQuaternion::from_euler_angles(self.rpy[0], self.rpy[1], self.rpy[2]),
        )
    }
}

/// The base as declared: three planar joints (x, y, yaw, any order along the chain) carrying
/// `link`, or none (a fixed-base arm on `link`).
#[derive(Debug, Clone, PartialEq)]
pub enum BaseDecl {
    Planar { joints: [String; 3], link: Option<String> },
    Fixed { link: Option<String> },
}

/// Every role a robot can declare; empty fields are detected from the tree (or stay absent).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RoleDecls {
    pub tool: Option<ToolSpec>,
    pub tool_frame: Option<String>,
    /// Movable joints fixed at a value (rad or m), like an object's `hold`.
    pub hold: Vec<(String, f64)>,
    pub base: Option<BaseDecl>,
    /// Joint values of the home posture; joints left out follow the rule of `Scene::home_configuration`.
    pub home: Vec<(String, f64)>,
    /// Joint values of the start posture (`sabre.start_state`), over the home posture.
    pub start: Vec<(String, f64)>,
    /// Joint values of the working posture (hand forward, margins on every limit) that scripted
    /// motions pull toward in their null space, over the home posture.
    pub work: Vec<(String, f64)>,
    pub wrist_sensor: Option<String>,
}

impl RoleDecls {
    /// These declarations with `options` over them: a role `options` gives replaces the declared
    /// one; held joints and postures are merged joint by joint.
    pub fn overridden_by(&self, options: &RoleDecls) -> RoleDecls {
        let merge = |base: &[(String, f64)], over: &[(String, f64)]| {
            let mut out: Vec<(String, f64)> = base
                .iter()
                .filter(|(n, _)| !over.iter().any(|(m, _)| m == n))
                .cloned()
                .collect();
            out.extend(over.iter().cloned());
            out
        };
        RoleDecls {
            tool: options.tool.clone().or_else(|| self.tool.clone()),
            tool_frame: options.tool_frame.clone().or_else(|| self.tool_frame.clone()),
            hold: merge(&self.hold, &options.hold),
            base: options.base.clone().or_else(|| self.base.clone()),
            home: merge(&self.home, &options.home),
            start: merge(&self.start, &options.start),
            work: merge(&self.work, &options.work),
            wrist_sensor: options.wrist_sensor.clone().or_else(|| self.wrist_sensor.clone()),
        }
    }
}

fn attribute(source: &str, node: &roxmltree::Node, name: &str) -> Result<String> {
    node.attribute(name).map(str::to_string).ok_or_else(|| {
        SabreError::urdf(
            source,
            format!("<sabre><{}> needs attribute '{name}'", node.tag_name().name()),
        )
    })
}

fn numbers<const N: usize>(source: &str, node: &roxmltree::Node, name: &str) -> Result<[f64; N]> {
    let Some(text) = node.attribute(name) else {
        return Ok([0.0; N]);
    };
    let values: Vec<f64> = text.split_whitespace().filter_map(|t| t.parse().ok()).collect();
    if values.len() != N || values.iter().any(|v| !v.is_finite()) {
        return Err(SabreError::urdf(
            source,
            format!(
                "<sabre><{}> {name}='{text}' must be {N} finite numbers",
                node.tag_name().name()
            ),
        ));
    }
    let mut out = [0.0; N];
    out.copy_from_slice(&values);
    Ok(out)
}

fn joint_value(source: &str, node: &roxmltree::Node) -> Result<(String, f64)> {
    let [value] = numbers::<1>(source, node, "value")?;
    if node.attribute("value").is_none() {
        return Err(SabreError::urdf(
            source,
            format!("<sabre><{}> needs attribute 'value'", node.tag_name().name()),
        ));
    }
    Ok((attribute(source, node, "joint")?, value))
}

fn tool(source: &str, node: &roxmltree::Node) -> Result<ToolSpec> {
    let origin = match (node.attribute("builtin"), node.attribute("file")) {
        (Some(name), None) => ToolSource::Builtin(name.to_string()),
        (None, Some(file)) => {
            let path = PathBuf::from(file);
            let dir = std::path::Path::new(source)
                .parent()
                .filter(|_| std::path::Path::new(source).is_file());
            ToolSource::File(match dir {
                Some(dir) if path.is_relative() => dir.join(path),
                _ => path,
            })
        }
        _ => {
            return Err(SabreError::urdf(
                source,
                "<sabre><tool> needs exactly one of 'builtin' (a shipped tool) and 'file' (a URDF fragment)",
            ))
        }
    };
    Ok(ToolSpec {
        parent: attribute(source, node, "parent")?,
        source: origin,
        xyz: numbers::<3>(source, node, "xyz")?,
        rpy: numbers::<3>(source, node, "rpy")?,
        frame: node.attribute("frame").map(str::to_string),
    })
}

fn base(source: &str, node: &roxmltree::Node) -> Result<BaseDecl> {
    let link = node.attribute("link").map(str::to_string);
    match node.attribute("type").map(str::trim) {
        Some("fixed") => Ok(BaseDecl::Fixed { link }),
        Some("planar") => {
            let joints: Vec<String> = attribute(source, node, "joints")?
                .split_whitespace()
                .map(str::to_string)
                .collect();
            let joints: [String; 3] = joints.try_into().map_err(|j: Vec<String>| {
                SabreError::urdf(
                    source,
                    format!(
                        "<sabre><base type=\"planar\"> needs three joints (x, y, yaw), got {}",
                        j.len()
                    ),
                )
            })?;
            Ok(BaseDecl::Planar { joints, link })
        }
        other => Err(SabreError::urdf(
            source,
            format!("<sabre><base> type must be \"planar\" or \"fixed\", got {other:?}"),
        )),
    }
}

/// Reads one role element of a `<sabre>` block into `decls`; false if `node` is no role element.
pub fn parse_role(source: &str, node: &roxmltree::Node, decls: &mut RoleDecls) -> Result<bool> {
    match node.tag_name().name() {
        "tool" => decls.tool = Some(tool(source, node)?),
        "tool_frame" => decls.tool_frame = Some(attribute(source, node, "link")?),
        "hold" => decls.hold.push(joint_value(source, node)?),
        "base" => decls.base = Some(base(source, node)?),
        "home" => decls.home.push(joint_value(source, node)?),
        "start" => decls.start.push(joint_value(source, node)?),
        "work" => decls.work.push(joint_value(source, node)?),
        "wrist_sensor" => decls.wrist_sensor = Some(attribute(source, node, "link")?),
        _ => return Ok(false),
    }
    Ok(true)
}

/// The URDF text of a tool and the name it goes by in messages.
pub fn tool_text(tool: &ToolSpec) -> Result<(String, String)> {
    match &tool.source {
        ToolSource::Builtin(name) => BUILTIN_TOOLS
            .iter()
            .find(|(n, _)| n == name)
            .map(|(n, text)| (format!("tool '{n}'"), text.to_string()))
            .ok_or_else(|| SabreError::UnknownAsset {
                kind: "tool".into(),
                name: name.clone(),
                available: BUILTIN_TOOLS.iter().map(|(n, _)| *n).collect::<Vec<_>>().join(", "),
            }),
        ToolSource::File(path) => {
            let name = path.display().to_string();
            let text =
                std::fs::read_to_string(path).map_err(|e| SabreError::urdf(&name, format!("cannot read tool file: {e}")))?;
            Ok((name, text))
        }
        ToolSource::Text { name, text } => Ok((name.clone(), text.clone())),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(body: &str) -> Result<RoleDecls> {
        let text = format!("<sabre>{body}</sabre>");
        let doc = roxmltree::Document::parse(&text).unwrap();
        let mut decls = RoleDecls::default();
        for node in doc.root_element().children().filter(|n| n.is_element()) {
            assert!(parse_role("robot", &node, &mut decls)?);
        }
        Ok(decls)
    }

    #[test]
    fn every_role_element_is_read() {
        let decls = parse(
            r#"<tool parent="hand" builtin="hook" xyz="0 0 0.05" frame="grasp"/><tool_frame link="tcp"/>
               <hold joint="finger" value="0.04"/><base type="planar" joints="x y yaw" link="body"/>
               <home joint="j2" value="-0.5"/><start joint="j2" value="-1"/><wrist_sensor link="flange"/>"#,
        )
        .unwrap();
        let tool = decls.tool.unwrap();
        assert_eq!(
            (tool.parent.as_str(), tool.xyz, tool.frame.as_deref()),
            ("hand", [0.0, 0.0, 0.05], Some("grasp"))
        );
        assert_eq!(tool.source, ToolSource::Builtin("hook".into()));
        assert_eq!(decls.tool_frame.as_deref(), Some("tcp"));
        assert_eq!(decls.hold, vec![("finger".to_string(), 0.04)]);
        assert_eq!(
            decls.base,
            Some(BaseDecl::Planar {
                joints: ["x".into(), "y".into(), "yaw".into()],
                link: Some("body".into())
            })
        );
        assert_eq!((decls.home[0].1, decls.start[0].1), (-0.5, -1.0));
        assert_eq!(decls.wrist_sensor.as_deref(), Some("flange"));
    }

    #[test]
    fn malformed_roles_name_what_is_wrong() {
        let message = |body: &str| parse(body).unwrap_err().to_string();
        assert!(message(r#"<tool parent="hand"/>"#).contains("'builtin'"));
        assert!(message(r#"<hold joint="f"/>"#).contains("'value'"));
        assert!(message(r#"<base type="planar" joints="x y"/>"#).contains("three joints"));
        assert!(message(r#"<base type="wheeled"/>"#).contains("planar"));
        assert!(message(r#"<tool parent="h" builtin="hook" xyz="0 0"/>"#).contains("3 finite numbers"));
    }

    #[test]
    fn options_replace_roles_and_merge_postures_joint_by_joint() {
        let declared = parse(r#"<tool_frame link="a"/><home joint="j1" value="1"/><home joint="j2" value="2"/>"#).unwrap();
        let options = RoleDecls {
            tool_frame: Some("b".into()),
            home: vec![("j2".into(), 5.0)],
            ..Default::default()
        };
        let merged = declared.overridden_by(&options);
        assert_eq!(merged.tool_frame.as_deref(), Some("b"));
        assert_eq!(merged.home, vec![("j1".to_string(), 1.0), ("j2".to_string(), 5.0)]);
    }
}
