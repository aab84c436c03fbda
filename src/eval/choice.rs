//! Which object a first target heads for: the open-loop probe's answer to "does the policy find the demonstrated
//! object in its own scene, head for another one, or copy the demonstrator's motion in the demonstrator's scene?".
//!
//! A target is read by its direction in the table plane from the gripper's start: it heads for the object of the
//! agent's scene whose bearing from the gripper is closest to the target's.
use crate::data::trajectory::Trajectory;
use crate::sim::task::Task;

/// The objects of both scenes at a trajectory pair's first frames, as the choice needs them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FirstScene {
    /// The agent's gripper position (x, y) at its first frame.
    pub start: [f64; 2],
    /// The four objects' positions (x, y) in the agent's first frame.
    pub objects: [[f64; 2]; 4],
    /// The demonstrated object's index and its position (x, y) in the demonstrator's first frame.
    pub demonstrated: usize,
    pub in_demonstration: [f64; 2],
}

impl FirstScene {
    /// The first frames of a demonstration and the agent trajectory it is paired with (same task).
    pub fn of(demo: &Trajectory, agent: &Trajectory) -> FirstScene {
        let object = Task::from_id(agent.meta.task).expect("a collected trajectory's task is valid").object;
        FirstScene::with_object(demo, agent, object)
    }

    /// The same, with `object` (a slot) as the demonstrated one: for a demonstration swapped in from another
    /// task.
    pub fn with_object(demo: &Trajectory, agent: &Trajectory, object: usize) -> FirstScene {
        let xy = |p: &[f32; 7]| [f64::from(p[0]), f64::from(p[1])];
        FirstScene {
            start: [f64::from(agent.eef_pos[0][0]), f64::from(agent.eef_pos[0][1])],
            objects: agent.object_poses[0].each_ref().map(xy),
            demonstrated: object,
            in_demonstration: xy(&demo.object_poses[0][object]),
        }
    }

    /// The object whose bearing from the gripper's start is closest to `target`'s (x, y), none when the target
    /// does not move the gripper in the plane (under a millimetre).
    pub fn heads_for(&self, target: [f64; 2]) -> Option<usize> {
        let bearing = |p: [f64; 2]| [p[0] - self.start[0], p[1] - self.start[1]];
        let t = bearing(target);
        if t[0].hypot(t[1]) < 1e-3 {
            return None;
        }
        (0..4).min_by(|&a, &b| angle(t, bearing(self.objects[a])).total_cmp(&angle(t, bearing(self.objects[b]))))
    }

    /// Whether `target` points closer to the demonstrated object's position in the demonstrator's scene than to
    /// its position in the agent's own.
    pub fn follows_demonstration_scene(&self, target: [f64; 2]) -> bool {
        let bearing = |p: [f64; 2]| [p[0] - self.start[0], p[1] - self.start[1]];
        let t = bearing(target);
        angle(t, bearing(self.in_demonstration)) < angle(t, bearing(self.objects[self.demonstrated]))
    }
}

/// Angle (radians) between two plane vectors.
fn angle(a: [f64; 2], b: [f64; 2]) -> f64 {
    let cross = a[0] * b[1] - a[1] * b[0];
    let dot = a[0] * b[0] + a[1] * b[1];
    cross.atan2(dot).abs()
}

/// How the first targets of a set of windows divide among the objects.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ChoiceCounts {
    /// Windows counted.
    pub windows: usize,
    /// Heading for the demonstrated object in the agent's scene.
    pub demonstrated: usize,
    /// Heading for one of the other three objects.
    pub other: usize,
    /// Not moving the gripper in the plane.
    pub still: usize,
    /// Pointing closer to the demonstrated object's place in the demonstrator's scene than in the agent's.
    pub demonstration_scene: usize,
}

impl ChoiceCounts {
    /// Counts one window's first target.
    pub fn add(&mut self, scene: &FirstScene, target: [f64; 2]) {
        self.windows += 1;
        match scene.heads_for(target) {
            Some(k) if k == scene.demonstrated => self.demonstrated += 1,
            Some(_) => self.other += 1,
            None => self.still += 1,
        }
        self.demonstration_scene += usize::from(scene.follows_demonstration_scene(target));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scene() -> FirstScene {
        // Gripper at the origin, objects to the east, north, west and south; object 1 demonstrated, and in the
        // demonstrator's scene it lay to the south-east.
        FirstScene {
            start: [0.0, 0.0],
            objects: [[0.1, 0.0], [0.0, 0.1], [-0.1, 0.0], [0.0, -0.1]],
            demonstrated: 1,
            in_demonstration: [0.1, -0.1],
        }
    }

    #[test]
    fn a_target_heads_for_the_object_at_its_bearing() {
        let s = scene();
        assert_eq!(s.heads_for([0.02, 0.005]), Some(0));
        assert_eq!(s.heads_for([0.001, 0.03]), Some(1));
        assert_eq!(s.heads_for([-0.05, -0.01]), Some(2));
        assert_eq!(s.heads_for([0.0002, 0.0]), None);
    }

    #[test]
    fn counts_separate_the_demonstrated_object_others_and_the_demonstration_scene() {
        let s = scene();
        let mut c = ChoiceCounts::default();
        for t in [[0.0, 0.05], [0.05, -0.05], [0.0, 0.0], [-0.05, 0.0]] {
            c.add(&s, t);
        }
        // North: the demonstrated object; south-east: object 0 or 3 (equal bearing, the first), and the
        // demonstration scene's place; still; west: another object.
        assert_eq!((c.windows, c.demonstrated, c.other, c.still), (4, 1, 2, 1));
        assert_eq!(c.demonstration_scene, 1);
    }
}
