//! The safety filter's sphere obstacles: added, moved and removed by id, each in a fixed slot of
//! the filter's obstacle rows (the QPs are built once with every slot).

use super::SafetyFilter;
use crate::error::{ensure_finite, Result, SabreError};
use crate::safety::config::ConstraintClass;
use crate::safety::constraints::Obstacle;

impl SafetyFilter {
    /// Adds a sphere obstacle (world centre, radius); returns its id. Fails when every slot is taken.
    pub fn add_obstacle(&mut self, center: [f64; 3], radius: f64) -> Result<u64> {
        ensure_finite("obstacle center", &center)?;
        if !(radius.is_finite() && radius > 0.0) {
            return Err(SabreError::invalid(
                "obstacle radius",
                format!("must be finite and positive, got {radius}"),
            ));
        }
        if !self.config.enabled.get(ConstraintClass::Obstacles) {
            return Err(SabreError::invalid(
                "obstacles",
                "the obstacle class is disabled in this filter's config",
            ));
        }
        let slot = self.obstacles.iter().position(|o| o.is_none()).ok_or_else(|| {
            SabreError::invalid(
                "obstacles",
                format!("all {} obstacle slots are in use; remove one first", self.obstacles.len()),
            )
        })?;
        let id = self.next_obstacle_id;
        self.next_obstacle_id += 1;
        self.obstacles[slot] = Some(Obstacle {
            id,
            center: center.into(),
            radius,
        });
        Ok(id)
    }

    fn obstacle_slot(&self, id: u64) -> Result<usize> {
        self.obstacles
            .iter()
            .position(|o| o.is_some_and(|o| o.id == id))
            .ok_or_else(|| SabreError::invalid("obstacle id", format!("no obstacle with id {id}")))
    }

    pub fn move_obstacle(&mut self, id: u64, center: [f64; 3]) -> Result<()> {
        ensure_finite("obstacle center", &center)?;
        let slot = self.obstacle_slot(id)?;
        if let Some(o) = self.obstacles[slot].as_mut() {
            o.center = center.into();
        }
        Ok(())
    }

    pub fn remove_obstacle(&mut self, id: u64) -> Result<()> {
        let slot = self.obstacle_slot(id)?;
        self.obstacles[slot] = None;
        Ok(())
    }

    /// The obstacles present, in slot order.
    pub fn obstacles(&self) -> impl Iterator<Item = &Obstacle> {
        self.obstacles.iter().flatten()
    }
}
