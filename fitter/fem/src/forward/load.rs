//! External loads: force-driven probe contacts spread with the runtime's contact rule
//! (`palpate_runtime::contact_rule`, used exactly), and explicit nodal forces.

use palpate_runtime::contact_rule::{contact_weights, ContactRuleError};

use super::{ForwardError, StaticProblem};

/// A force-driven probe contact (seed 000 §4.1): force vector spread over the free surface nodes
/// within `radius` of `point` by lumped surface area.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Contact {
    /// Contact point on the rest surface (m).
    pub point: [f64; 3],
    /// Force vector (N).
    pub force: [f64; 3],
    /// Probe radius (m).
    pub radius: f64,
}

/// External load of one static problem.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Load {
    /// Probe contacts.
    pub contacts: Vec<Contact>,
    /// Explicit nodal forces (node index, N).
    pub nodal: Vec<(usize, [f64; 3])>,
}

impl Load {
    /// A load of one contact.
    pub fn contact(point: [f64; 3], force: [f64; 3], radius: f64) -> Self {
        Self {
            contacts: vec![Contact {
                point,
                force,
                radius,
            }],
            nodal: Vec::new(),
        }
    }
}

impl StaticProblem {
    /// The full 3n nodal force vector of `load` (forces on fixed nodes from nodal loads are kept
    /// but have no effect: fixed dofs are eliminated).
    pub fn force_vector(&self, load: &Load) -> Result<Vec<f64>, ForwardError> {
        let n = self.x0.len();
        let mut f = vec![0.0; 3 * n];
        for (index, c) in load.contacts.iter().enumerate() {
            let err = |reason: String| ForwardError::Contact {
                index,
                point: c.point,
                radius: c.radius,
                reason,
            };
            if !c.force.iter().all(|v| v.is_finite()) {
                return Err(err(format!("force {:?} is not finite", c.force)));
            }
            contact_weights(
                c.point,
                c.radius,
                |i| self.x0[i],
                &self.areas,
                |i| self.fixed[i],
                |i, w| {
                    for d in 0..3 {
                        f[3 * i + d] += w * c.force[d];
                    }
                },
            )
            .map_err(|e| match e {
                ContactRuleError::NoNodeInRadius { nearest } => err(format!(
                    "no free surface node within the probe radius (nearest is {nearest:.4e} m away)"
                )),
                ContactRuleError::BadInput => {
                    err("radius must be positive and the point finite".into())
                }
            })?;
        }
        for (index, &(node, force)) in load.nodal.iter().enumerate() {
            if node >= n {
                return Err(ForwardError::NodalForce {
                    index,
                    node,
                    reason: "node index out of range",
                });
            }
            if !force.iter().all(|v| v.is_finite()) {
                return Err(ForwardError::NodalForce {
                    index,
                    node,
                    reason: "force is not finite",
                });
            }
            for d in 0..3 {
                f[3 * node + d] += force[d];
            }
        }
        Ok(f)
    }
}
