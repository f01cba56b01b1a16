//! The robot's safety geometry as a scene holds it: collision spheres, their self-collision pairs,
//! the rollout model's contact links and the arm's planar reach; and what of it a robot's `<sabre>`
//! block declares (`super::generated` makes it for a robot whose block declares none).

use nalgebra::Vector3;

use super::kinematics::KinematicTree;
use super::urdf::SabreExtension;
use crate::error::{Result, SabreError};

/// A collision sphere attached to a robot link, in the self-collision pairs that name it and,
/// where `obstacles`, against run-time sphere obstacles (see `SphereDecl`).
#[derive(Debug, Clone, PartialEq)]
pub struct Sphere {
    pub name: String,
    pub link: usize,
    pub center: Vector3<f64>,
    pub radius: f64,
    pub obstacles: bool,
}

#[derive(Debug, Clone, PartialEq)]
pub struct ArmReach {
    pub base_link: usize,
    pub frame_link: usize,
    pub max: f64,
}

/// Where the scene's safety geometry came from: "declared" in the robot's `<sabre>` block or
/// "generated" from its tree (`super::generated`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct GeometryOrigin(pub &'static str);

/// Checks that every link and sphere the `<sabre>` block names exists in `tree` (the robot with its
/// tool attached).
pub(super) fn check_extension(source: &str, tree: &KinematicTree, extension: &SabreExtension) -> Result<()> {
    for name in extension
        .rollout_contact_links
        .iter()
        .chain(extension.spheres.iter().map(|s| &s.link))
        .chain(extension.arm_reach.iter().flat_map(|a| [&a.base, &a.frame]))
    {
        if tree.link_id(name).is_none() {
            return Err(SabreError::urdf(source, format!("<sabre> refers to unknown link '{name}'")));
        }
    }
    for (a, b) in &extension.pairs {
        for s in [a, b] {
            if !extension.spheres.iter().any(|sp| &sp.name == s) {
                return Err(SabreError::urdf(
                    source,
                    format!("<sabre><pair> refers to unknown sphere '{s}'"),
                ));
            }
        }
    }
    Ok(())
}

/// The spheres, pairs, contact links and reach a robot's `<sabre>` block declares (checked by
/// `check_extension`); without declared contact links every link with collision geometry touches.
#[allow(clippy::type_complexity)]
pub(super) fn declared_geometry(
    tree: &KinematicTree,
    ext: &SabreExtension,
) -> (Vec<Sphere>, Vec<(usize, usize)>, Vec<usize>, Option<ArmReach>) {
    let spheres: Vec<Sphere> = ext
        .spheres
        .iter()
        .map(|s| Sphere {
            name: s.name.clone(),
            link: tree.link_id(&s.link).expect("checked"),
            center: s.center,
            radius: s.radius,
            obstacles: s.obstacles,
        })
        .collect();
    let sphere_index = |name: &str| spheres.iter().position(|s| s.name == name).expect("checked");
    let pairs = ext.pairs.iter().map(|(a, b)| (sphere_index(a), sphere_index(b))).collect();
    let mut contact: Vec<usize> = ext
        .rollout_contact_links
        .iter()
        .map(|n| tree.link_id(n).expect("checked"))
        .collect();
    if contact.is_empty() {
        contact = (0..tree.links.len())
            .filter(|&l| !tree.links[l].collisions.is_empty())
            .collect();
    }
    let reach = ext.arm_reach.as_ref().map(|a| ArmReach {
        base_link: tree.link_id(&a.base).expect("checked"),
        frame_link: tree.link_id(&a.frame).expect("checked"),
        max: a.max,
    });
    (spheres, pairs, contact, reach)
}
