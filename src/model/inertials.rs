//! Inertials a URDF leaves out: the mass, centre of mass and inertia of the object's moving links
//! filled in from their collision geometry at a density when the file does not give them (what it
//! does declare is each link's `DeclaredInertial`).
//!
//! Models exported for robot learning often carry no `<inertial>` at all, or a mass without an
//! inertia tensor. Each of mass, centre of mass and inertia that a moving object link leaves out
//! is taken from its collision primitives filled with material of one density: the mass as density
//! × volume, the centre of mass as the solids' centroid, the inertia as the solids' (scaled to a
//! declared mass when there is one). A declared part is kept.

use nalgebra::{Matrix3, Vector3};

use super::collision_shape::geometry_inertial;
use super::description::{check_inertia, Inertial};
use super::kinematics::KinematicTree;
use crate::error::{Result, SabreError};

/// Density (kg/m³) of the material moving object parts are assumed to be made of when their file
/// gives no inertial: medium-density fibreboard and particle board, which most cabinet doors,
/// drawer fronts and drawer boxes are made of, weigh 600–750 kg/m³ and solid pine about 500.
pub const DEFAULT_DENSITY: f64 = 600.0;

/// A moving object link's inertial that sabre filled in, as the scene reports it.
#[derive(Debug, Clone, PartialEq)]
pub struct AssumedInertial {
    pub link: String,
    pub mass: f64,
    /// Centre of mass in the link frame (m).
    pub com: Vector3<f64>,
    /// Inertia about the centre of mass, in the link frame (kg m²).
    pub inertia: Matrix3<f64>,
    /// Where the values come from, e.g. "collision geometry at 600 kg/m³".
    pub source: String,
}

/// Fills in the inertial of every link of the object `tree` that a movable joint moves, has
/// collision geometry and whose file leaves out part of its inertial, from that geometry at
/// `density` (kg/m³); returns what it assumed, link by link.
pub fn assume_missing(tree: &mut KinematicTree, density: f64, source: &str) -> Result<Vec<AssumedInertial>> {
    if !(density.is_finite() && density > 0.0) {
        return Err(SabreError::invalid(
            "density",
            format!("must be positive and finite (kg/m³), got {density}"),
        ));
    }
    let mut assumed = Vec::new();
    for link in 0..tree.links.len() {
        let moving = !tree.ancestor_active_joints(link).is_empty();
        let l = &tree.links[link];
        let Some(declared) = l.declared_inertial.filter(|_| moving && l.inertial.is_none()) else {
            continue;
        };
        let Some(solid) = geometry_inertial(&l.collisions, density) else {
            continue;
        };
        let mass = declared.mass.unwrap_or(solid.mass);
        let inertia = declared.inertia.unwrap_or(solid.inertia * (mass / solid.mass));
        let com = declared.com.unwrap_or(solid.com);
        let kept: Vec<&str> = [
            ("mass", declared.mass.is_some()),
            ("centre of mass", declared.com.is_some()),
            ("inertia", declared.inertia.is_some()),
        ]
        .iter()
        .filter(|(_, given)| *given)
        .map(|(what, _)| *what)
        .collect();
        let from = format!("collision geometry at {density} kg/m³");
        let described = if kept.is_empty() {
            from
        } else {
            format!("{from}; declared {}", kept.join(", "))
        };
        let inertial = Inertial { mass, com, inertia };
        check_inertia(source, &l.name, &inertial.inertia)?;
        assumed.push(AssumedInertial {
            link: l.name.clone(),
            mass,
            com,
            inertia,
            source: described,
        });
        tree.set_inertial(link, Some(inertial));
    }
    Ok(assumed)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::scene::{Scene, BUILTIN_ROBOTS};

    fn object(tray_inertial: &str) -> String {
        format!(
            r#"<robot name="o"><link name="body"/>
            <link name="tray">{tray_inertial}<collision><origin xyz="0.1 0 0"/><geometry><box size="0.2 0.4 0.02"/></geometry></collision></link>
            <joint name="slide" type="prismatic"><parent link="body"/><child link="tray"/><axis xyz="-1 0 0"/>
            <limit lower="0" upper="0.3" effort="1" velocity="1"/></joint></robot>"#
        )
    }

    fn tray(inertial: &str, density: f64) -> (Inertial, Vec<AssumedInertial>) {
        let scene = Scene::from_urdf_strings(BUILTIN_ROBOTS[0].1, &object(inertial), None)
            .unwrap()
            .with_density(density)
            .unwrap();
        let link = scene.object.link_id("tray").unwrap();
        (scene.object.links[link].inertial.unwrap(), scene.assumed_inertials)
    }

    #[test]
    fn an_inertial_without_mass_or_inertia_keeps_what_it_declares() {
        let (full, assumed) = tray("", 500.0);
        let m = 500.0 * 0.2 * 0.4 * 0.02;
        assert!((full.mass - m).abs() < 1e-12 && (full.com - Vector3::new(0.1, 0.0, 0.0)).norm() < 1e-12);
        assert_eq!(assumed.len(), 1);
        assert_eq!(assumed[0].source, "collision geometry at 500 kg/m³");
        let (declared, assumed) = tray(r#"<inertial><origin xyz="0.05 0 0"/><mass value="3"/></inertial>"#, 500.0);
        assert_eq!((declared.mass, declared.com), (3.0, Vector3::new(0.05, 0.0, 0.0)));
        assert!((declared.inertia - full.inertia * (3.0 / m)).norm() < 1e-12);
        assert_eq!(
            assumed[0].source,
            "collision geometry at 500 kg/m³; declared mass, centre of mass"
        );
        let complete =
            r#"<inertial><mass value="1"/><inertia ixx="0.1" ixy="0" ixz="0" iyy="0.1" iyz="0" izz="0.1"/></inertial>"#;
        assert!(tray(complete, 500.0).1.is_empty());
    }

    #[test]
    fn a_changed_density_or_joint_choice_recomputes_what_was_assumed() {
        let text = object("");
        let light = Scene::from_urdf_strings(BUILTIN_ROBOTS[0].1, &text, None).unwrap();
        let heavy = light.clone().with_density(1200.0).unwrap();
        assert!((heavy.assumed_inertials[0].mass - 2.0 * light.assumed_inertials[0].mass).abs() < 1e-12);
        let again = heavy.with_object_joint(Some("slide"), &[], Some("tray")).unwrap();
        assert_eq!(again.density, 1200.0);
        assert!((again.assumed_inertials[0].mass - 2.0 * light.assumed_inertials[0].mass).abs() < 1e-12);
        assert!(light.with_density(f64::NAN).is_err());
    }
}
