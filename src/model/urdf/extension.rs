//! sabre's `<sabre>` block of a robot URDF: collision spheres and their pairs, the rollout model's
//! contact links, the arm's reach and the roles of the robot's parts, as declared.

use nalgebra::Vector3;

use crate::error::{Result, SabreError};
use crate::model::roles::{parse_role, RoleDecls};

/// A collision sphere rigidly attached to a robot link, for the self-collision pairs that name it
/// and, unless `obstacles="false"`, against run-time sphere obstacles. A self-collision sphere may
/// be larger than its link to encode a minimum distance between two links; against an obstacle a
/// sphere only needs to cover the link's geometry, so such a link gets a second, obstacle-only
/// sphere (one in no pair).
#[derive(Debug, Clone, PartialEq)]
pub struct SphereDecl {
    pub name: String,
    pub link: String,
    pub center: Vector3<f64>,
    pub radius: f64,
    pub obstacles: bool,
}

/// Planar reach limit of a frame relative to the arm base (paper eqs. 32 and 40).
#[derive(Debug, Clone, PartialEq)]
pub struct ArmReachDecl {
    pub base: String,
    pub frame: String,
    pub max: f64,
}

/// Contents of the optional `<sabre>` block of a robot URDF.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SabreExtension {
    pub rollout_contact_links: Vec<String>,
    pub spheres: Vec<SphereDecl>,
    pub pairs: Vec<(String, String)>,
    pub arm_reach: Option<ArmReachDecl>,
    /// The tool, control frame, held joints, base and postures it declares.
    pub roles: RoleDecls,
}

fn parse_f64(source: &str, node: &roxmltree::Node, attr: &str) -> Result<f64> {
    let text = node.attribute(attr).ok_or_else(|| {
        SabreError::urdf(
            source,
            format!("<sabre><{}> needs attribute '{attr}'", node.tag_name().name()),
        )
    })?;
    text.trim().parse::<f64>().ok().filter(|v| v.is_finite()).ok_or_else(|| {
        SabreError::urdf(
            source,
            format!(
                "<sabre><{}> attribute '{attr}'='{text}' is not a finite number",
                node.tag_name().name()
            ),
        )
    })
}

fn parse_xyz(source: &str, node: &roxmltree::Node) -> Result<Vector3<f64>> {
    let Some(text) = node.attribute("xyz") else {
        return Ok(Vector3::zeros());
    };
    let values: Vec<f64> = text.split_whitespace().filter_map(|t| t.parse().ok()).collect();
    if values.len() != 3 || values.iter().any(|v: &f64| !v.is_finite()) {
        return Err(SabreError::urdf(
            source,
            format!("<sabre> xyz='{text}' must be three finite numbers"),
        ));
    }
    Ok(Vector3::new(values[0], values[1], values[2]))
}

pub(super) fn parse_extension(source: &str, doc: &roxmltree::Document) -> Result<SabreExtension> {
    let mut ext = SabreExtension::default();
    let Some(block) = doc.root_element().children().find(|n| n.has_tag_name("sabre")) else {
        return Ok(ext);
    };
    for node in block.children().filter(|n| n.is_element()) {
        let attr = |name: &str| {
            node.attribute(name).map(str::to_string).ok_or_else(|| {
                SabreError::urdf(
                    source,
                    format!("<sabre><{}> needs attribute '{name}'", node.tag_name().name()),
                )
            })
        };
        match node.tag_name().name() {
            "rollout_contact" => ext
                .rollout_contact_links
                .extend(attr("links")?.split_whitespace().map(str::to_string)),
            "sphere" => {
                let radius = parse_f64(source, &node, "radius")?;
                if radius <= 0.0 {
                    return Err(SabreError::urdf(source, "<sabre><sphere> radius must be positive"));
                }
                let obstacles = match node.attribute("obstacles").map(str::trim) {
                    None | Some("true") => true,
                    Some("false") => false,
                    Some(other) => {
                        return Err(SabreError::urdf(
                            source,
                            format!("<sabre><sphere> attribute 'obstacles'='{other}' must be true or false"),
                        ))
                    }
                };
                ext.spheres.push(SphereDecl {
                    name: attr("name")?,
                    link: attr("link")?,
                    center: parse_xyz(source, &node)?,
                    radius,
                    obstacles,
                });
            }
            "pair" => ext.pairs.push((attr("a")?, attr("b")?)),
            "arm_reach" => {
                ext.arm_reach = Some(ArmReachDecl {
                    base: attr("base")?,
                    frame: attr("frame")?,
                    max: parse_f64(source, &node, "max")?,
                })
            }
            other => {
                if !parse_role(source, &node, &mut ext.roles)? {
                    return Err(SabreError::urdf(source, format!("unknown element <sabre><{other}>")));
                }
            }
        }
    }
    Ok(ext)
}
