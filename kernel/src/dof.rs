//! Human DOF labels (`12:uz`) and the map between labels and matrix indices.
//!
//! Users name DOFs by node id and component, never by matrix index. A label is
//! `NODE:COMP` with `NODE` a non-negative integer and `COMP` one of `ux uy uz rx ry rz`
//! (translations in m, rotations in rad) or `u` for a scalar DOF of a lumped model.

use crate::error::{Error, Result};
use std::collections::HashMap;
use std::fmt;
use std::str::FromStr;

/// The component of a node's motion that a DOF describes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Component {
    /// Translation along x (m).
    Ux,
    /// Translation along y (m).
    Uy,
    /// Translation along z (m).
    Uz,
    /// Rotation about x (rad).
    Rx,
    /// Rotation about y (rad).
    Ry,
    /// Rotation about z (rad).
    Rz,
    /// The single coordinate of a scalar (lumped) DOF (m).
    U,
}

impl Component {
    /// All components, in the order nodes of 3-D frames carry them.
    pub const ALL: [Component; 7] = [
        Component::Ux,
        Component::Uy,
        Component::Uz,
        Component::Rx,
        Component::Ry,
        Component::Rz,
        Component::U,
    ];

    /// The text form used in labels.
    pub fn as_str(self) -> &'static str {
        match self {
            Component::Ux => "ux",
            Component::Uy => "uy",
            Component::Uz => "uz",
            Component::Rx => "rx",
            Component::Ry => "ry",
            Component::Rz => "rz",
            Component::U => "u",
        }
    }

    /// True for the translations `ux uy uz u` (unit m), false for rotations (rad).
    pub fn is_translation(self) -> bool {
        !matches!(self, Component::Rx | Component::Ry | Component::Rz)
    }
}

impl fmt::Display for Component {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// A DOF named by node id and component, written `12:uz`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct DofLabel {
    /// Node id as the user's mesh numbers it.
    pub node: u64,
    /// Component of the node's motion.
    pub component: Component,
}

impl DofLabel {
    /// A label from its parts.
    pub const fn new(node: u64, component: Component) -> Self {
        DofLabel { node, component }
    }
}

impl fmt::Display for DofLabel {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}:{}", self.node, self.component)
    }
}

impl FromStr for DofLabel {
    type Err = Error;

    fn from_str(s: &str) -> Result<Self> {
        let bad = |reason: &str| Error::InvalidDofLabel {
            label: s.to_string(),
            reason: reason.to_string(),
        };
        let (node, comp) = s
            .trim()
            .split_once(':')
            .ok_or_else(|| bad("expected NODE:COMPONENT, e.g. 12:uz"))?;
        let node: u64 = node
            .trim()
            .parse()
            .map_err(|_| bad("the node id must be a non-negative integer"))?;
        let comp = comp.trim().to_ascii_lowercase();
        let component = Component::ALL
            .into_iter()
            .find(|c| c.as_str() == comp)
            .ok_or_else(|| bad("the component must be one of ux, uy, uz, rx, ry, rz, u"))?;
        Ok(DofLabel { node, component })
    }
}

/// The ordered DOFs of a model: index `i` of every matrix and vector is DOF `labels[i]`.
#[derive(Debug, Clone, PartialEq)]
pub struct DofMap {
    labels: Vec<DofLabel>,
    index: HashMap<DofLabel, usize>,
}

impl DofMap {
    /// A map from labels in matrix order; fails on a repeated label.
    pub fn new(labels: Vec<DofLabel>) -> Result<Self> {
        let mut index = HashMap::with_capacity(labels.len());
        for (i, l) in labels.iter().enumerate() {
            if let Some(first) = index.insert(*l, i) {
                return Err(Error::DuplicateDof {
                    label: l.to_string(),
                    first,
                    second: i,
                });
            }
        }
        Ok(DofMap { labels, index })
    }

    /// `n` scalar DOFs labelled `1:u … n:u`, for lumped models.
    pub fn scalar(n: usize) -> Self {
        let labels = (1..=n as u64)
            .map(|node| DofLabel::new(node, Component::U))
            .collect();
        // Labels are distinct by construction.
        DofMap::new(labels).unwrap_or_else(|_| unreachable!())
    }

    /// Number of DOFs.
    pub fn len(&self) -> usize {
        self.labels.len()
    }

    /// True when there are no DOFs.
    pub fn is_empty(&self) -> bool {
        self.labels.is_empty()
    }

    /// The labels in matrix order.
    pub fn labels(&self) -> &[DofLabel] {
        &self.labels
    }

    /// The label of matrix index `i` (panics if out of range: indices come from the model).
    pub fn label(&self, i: usize) -> DofLabel {
        self.labels[i]
    }

    /// The label of index `i` as text, or `#i` when `i` is outside the map.
    pub fn describe(&self, i: usize) -> String {
        self.labels
            .get(i)
            .map_or_else(|| format!("#{i}"), |l| l.to_string())
    }

    /// The matrix index of a label.
    pub fn index_of(&self, label: &DofLabel) -> Result<usize> {
        self.index
            .get(label)
            .copied()
            .ok_or_else(|| Error::UnknownDof {
                label: label.to_string(),
                hint: self.hint_for(label),
            })
    }

    /// The matrix index of a label given as text (`"12:uz"`).
    pub fn find(&self, label: &str) -> Result<usize> {
        self.index_of(&label.parse()?)
    }

    fn hint_for(&self, label: &DofLabel) -> String {
        let comps: Vec<&str> = self
            .labels
            .iter()
            .filter(|l| l.node == label.node)
            .map(|l| l.component.as_str())
            .collect();
        if !comps.is_empty() {
            return format!(
                " (node {} has components {}; a DOF constrained or condensed out of the FE \
                 model's matrices is not in the model)",
                label.node,
                comps.join(", ")
            );
        }
        let (lo, hi) = self.labels.iter().fold((u64::MAX, 0), |(lo, hi), l| {
            (lo.min(l.node), hi.max(l.node))
        });
        if self.labels.is_empty() {
            String::new()
        } else {
            format!(
                " (node ids run from {lo} to {hi}, and node {} has no free DOF)",
                label.node
            )
        }
    }
}
