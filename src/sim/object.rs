//! The objects: the base world's four (milk, bread, cereal, can) and the multi-object library of 30 procedural
//! objects (the paper's appendix: 26 used in training, 4 only at test time), each a primitive or a primitive with
//! a small one on top, with its own colours and surface pattern. Every object is an index into one catalogue;
//! the library and its training / held-out split are written out here, never drawn at run time.
use rand::SeedableRng;
use rand::seq::SliceRandom;
use rand_chacha::ChaCha8Rng;

/// A primitive shape, centred on its body's origin.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Shape {
    /// Box with half-sizes (x, y, z); its narrow side is y.
    Box([f64; 3]),
    /// Upright cylinder with radius and half-height.
    Cylinder { radius: f64, half_height: f64 },
    /// Sphere of a radius.
    Sphere(f64),
    /// Ellipsoid with half-axes (x, y, z); its narrow side is y.
    Ellipsoid([f64; 3]),
}

impl Shape {
    /// Half extents (x, y, z) of its bounding box.
    pub fn half_extents(self) -> [f64; 3] {
        match self {
            Shape::Box(h) | Shape::Ellipsoid(h) => h,
            Shape::Cylinder { radius, half_height } => [radius, radius, half_height],
            Shape::Sphere(r) => [r, r, r],
        }
    }

    /// MuJoCo's `type` and `size` attributes.
    pub fn mjcf(self) -> String {
        match self {
            Shape::Box([x, y, z]) => format!(r#"type="box" size="{x} {y} {z}""#),
            Shape::Cylinder { radius, half_height } => format!(r#"type="cylinder" size="{radius} {half_height}""#),
            Shape::Sphere(r) => format!(r#"type="sphere" size="{r}""#),
            Shape::Ellipsoid([x, y, z]) => format!(r#"type="ellipsoid" size="{x} {y} {z}""#),
        }
    }
}

/// The surface of a library object: plain, or a built-in MuJoCo texture in its colour and a second one.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Pattern {
    Plain,
    Checker([f32; 3]),
    Stripes([f32; 3]),
}

/// One object: the body the gripper closes on, an optional small part resting on top of it (centred, narrower
/// than the body's narrow side so the fingers pass it), and its looks.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ObjectModel {
    pub name: &'static str,
    pub body: Shape,
    pub top: Option<Shape>,
    pub rgba: [f32; 4],
    pub pattern: Pattern,
}

const fn plain(name: &'static str, body: Shape, rgb: [f32; 3]) -> ObjectModel {
    ObjectModel { name, body, top: None, rgba: [rgb[0], rgb[1], rgb[2], 1.0], pattern: Pattern::Plain }
}

const fn patterned(name: &'static str, body: Shape, rgb: [f32; 3], pattern: Pattern) -> ObjectModel {
    ObjectModel { name, body, top: None, rgba: [rgb[0], rgb[1], rgb[2], 1.0], pattern }
}

const fn topped(name: &'static str, body: Shape, top: Shape, rgb: [f32; 3], pattern: Pattern) -> ObjectModel {
    ObjectModel { name, body, top: Some(top), rgba: [rgb[0], rgb[1], rgb[2], 1.0], pattern }
}

const fn cyl(radius: f64, half_height: f64) -> Shape {
    Shape::Cylinder { radius, half_height }
}

/// The base world's objects, then the library's, in catalogue order.
const CATALOGUE: [ObjectModel; 4 + LIBRARY_SIZE] = [
    // The base world (task order: milk, bread, cereal, can).
    plain("milk", Shape::Box([0.020, 0.020, 0.050]), [0.95, 0.95, 0.92]),
    plain("bread", Shape::Box([0.030, 0.018, 0.025]), [0.80, 0.55, 0.25]),
    plain("cereal", Shape::Box([0.027, 0.016, 0.045]), [0.85, 0.15, 0.12]),
    plain("can", cyl(0.021, 0.040), [0.20, 0.45, 0.85]),
    // The library: boxes.
    plain("box_tictac", Shape::Box([0.018, 0.012, 0.030]), [0.95, 0.85, 0.20]),
    patterned("box_tea", Shape::Box([0.030, 0.020, 0.035]), [0.20, 0.60, 0.30], Pattern::Stripes([0.9, 0.9, 0.8])),
    plain("box_soap", Shape::Box([0.028, 0.018, 0.026]), [0.70, 0.80, 0.95]),
    patterned("box_crackers", Shape::Box([0.032, 0.016, 0.045]), [0.90, 0.50, 0.10], Pattern::Checker([0.5, 0.2, 0.0])),
    plain("box_cube", Shape::Box([0.024, 0.024, 0.024]), [0.55, 0.25, 0.70]),
    patterned("box_juice", Shape::Box([0.022, 0.020, 0.055]), [0.98, 0.65, 0.15], Pattern::Stripes([0.2, 0.6, 0.2])),
    plain("box_brick", Shape::Box([0.034, 0.017, 0.025]), [0.70, 0.25, 0.20]),
    patterned("box_dice", Shape::Box([0.024, 0.024, 0.024]), [0.95, 0.95, 0.95], Pattern::Checker([0.1, 0.1, 0.1])),
    plain("box_matches", Shape::Box([0.026, 0.014, 0.028]), [0.30, 0.30, 0.80]),
    patterned("box_chips", Shape::Box([0.030, 0.015, 0.050]), [0.15, 0.15, 0.55], Pattern::Stripes([0.95, 0.8, 0.1])),
    plain("box_eraser", Shape::Box([0.025, 0.013, 0.024]), [0.95, 0.55, 0.65]),
    // Cylinders.
    plain("cyl_tallcan", cyl(0.021, 0.048), [0.75, 0.75, 0.78]),
    patterned("cyl_soup", cyl(0.024, 0.035), [0.85, 0.10, 0.10], Pattern::Stripes([0.95, 0.95, 0.95])),
    plain("cyl_puck", cyl(0.027, 0.024), [0.10, 0.10, 0.12]),
    patterned("cyl_sprite", cyl(0.022, 0.045), [0.20, 0.70, 0.35], Pattern::Checker([0.9, 0.9, 0.3])),
    plain("cyl_candle", cyl(0.018, 0.040), [0.95, 0.90, 0.75]),
    plain("cyl_tuna", cyl(0.026, 0.026), [0.35, 0.55, 0.75]),
    patterned("cyl_spool", cyl(0.021, 0.030), [0.60, 0.35, 0.15], Pattern::Stripes([0.9, 0.6, 0.6])),
    plain("cyl_marker", cyl(0.016, 0.050), [0.10, 0.30, 0.20]),
    // Spheres.
    plain("sph_orange", Shape::Sphere(0.028), [1.00, 0.55, 0.05]),
    plain("sph_plum", Shape::Sphere(0.027), [0.45, 0.10, 0.45]),
    patterned("sph_ball", Shape::Sphere(0.028), [0.95, 0.95, 0.95], Pattern::Checker([0.85, 0.1, 0.1])),
    // Ellipsoids.
    plain("ell_lemon", Shape::Ellipsoid([0.034, 0.025, 0.026]), [0.98, 0.90, 0.20]),
    plain("ell_egg", Shape::Ellipsoid([0.024, 0.022, 0.032]), [0.95, 0.90, 0.80]),
    patterned(
        "ell_melon",
        Shape::Ellipsoid([0.036, 0.026, 0.026]),
        [0.40, 0.70, 0.30],
        Pattern::Stripes([0.2, 0.4, 0.1]),
    ),
    plain("ell_potato", Shape::Ellipsoid([0.032, 0.024, 0.025]), [0.65, 0.50, 0.30]),
    // Compounds: a body with a small part on top.
    topped("cmp_bottle", cyl(0.022, 0.040), cyl(0.009, 0.012), [0.25, 0.50, 0.20], Pattern::Plain),
    topped("cmp_jar", cyl(0.026, 0.028), cyl(0.020, 0.006), [0.90, 0.70, 0.40], Pattern::Stripes([0.5, 0.3, 0.1])),
    topped(
        "cmp_gift",
        Shape::Box([0.024, 0.020, 0.024]),
        Shape::Sphere(0.010),
        [0.80, 0.10, 0.40],
        Pattern::Checker([0.95, 0.85, 0.2]),
    ),
    topped("cmp_lamp", Shape::Box([0.026, 0.018, 0.030]), cyl(0.012, 0.008), [0.20, 0.35, 0.60], Pattern::Plain),
];

/// Objects in the library.
pub const LIBRARY_SIZE: usize = 30;

/// The library's held-out objects (one box, one cylinder, one ellipsoid, one compound): never in a training
/// collection, the only objects of the test environments.
pub const HELD_OUT: [&str; 4] = ["box_tea", "cyl_sprite", "ell_lemon", "cmp_jar"];

/// One object of the catalogue.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Object(u8);

impl Object {
    pub const MILK: Object = Object(0);
    pub const BREAD: Object = Object(1);
    pub const CEREAL: Object = Object(2);
    pub const CAN: Object = Object(3);
    /// The base world's objects in task order (task = object * 4 + target).
    pub const ALL: [Object; 4] = [Object::MILK, Object::BREAD, Object::CEREAL, Object::CAN];

    /// Every object of the library, in catalogue order.
    pub fn library() -> impl Iterator<Item = Object> {
        (4..4 + LIBRARY_SIZE as u8).map(Object)
    }

    /// The library object called `name`.
    pub fn named(name: &str) -> Option<Object> {
        (0..CATALOGUE.len() as u8).map(Object).find(|o| o.name() == name)
    }

    fn model(self) -> &'static ObjectModel {
        &CATALOGUE[self.0 as usize]
    }

    /// Lower-case name.
    pub fn name(self) -> &'static str {
        self.model().name
    }

    /// The part the gripper closes on.
    pub fn shape(self) -> Shape {
        self.model().body
    }

    /// The small part on top of it, if any.
    pub fn top(self) -> Option<Shape> {
        self.model().top
    }

    /// Base colour (RGBA).
    pub fn rgba(self) -> [f32; 4] {
        self.model().rgba
    }

    /// Surface pattern.
    pub fn pattern(self) -> Pattern {
        self.model().pattern
    }

    /// Height of the object's centre above the surface it rests on.
    pub fn half_height(self) -> f64 {
        self.shape().half_extents()[2]
    }

    /// Radius of the object's footprint, for placement clearance.
    pub fn footprint_radius(self) -> f64 {
        match self.shape() {
            Shape::Box([x, y, _]) | Shape::Ellipsoid([x, y, _]) => x.hypot(y),
            Shape::Cylinder { radius, .. } => radius,
            Shape::Sphere(r) => r,
        }
    }

    /// Whether it is one of the library's held-out objects.
    pub fn held_out(self) -> bool {
        HELD_OUT.contains(&self.name())
    }
}

/// Which of the library's objects an environment draws from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Split {
    /// The 26 training objects.
    Train,
    /// The 4 held-out objects.
    HeldOut,
}

/// The library objects of `split`, in catalogue order.
pub fn split_objects(split: Split) -> Vec<Object> {
    Object::library().filter(|o| o.held_out() == (split == Split::HeldOut)).collect()
}

/// The four objects of the library environment with seed `seed`, in slot order: four distinct objects of
/// `split`, drawn by the seed alone (a held-out environment holds all four held-out objects, in its own order).
pub fn environment_objects(split: Split, seed: u64) -> [Object; 4] {
    let mut pool = split_objects(split);
    pool.shuffle(&mut ChaCha8Rng::seed_from_u64(seed ^ 0x0b1e_c75e_ed00_0000));
    [pool[0], pool[1], pool[2], pool[3]]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_library_is_thirty_named_objects_split_twenty_six_four() {
        let all: Vec<Object> = Object::library().collect();
        assert_eq!(all.len(), 30);
        let names: std::collections::BTreeSet<&str> = all.iter().map(|o| o.name()).collect();
        assert_eq!(names.len(), 30, "names are unique");
        let (train, held) = (split_objects(Split::Train), split_objects(Split::HeldOut));
        assert_eq!((train.len(), held.len()), (26, 4));
        assert!(train.iter().all(|o| !held.contains(o)));
        assert_eq!(held.iter().map(|o| o.name()).collect::<Vec<_>>(), HELD_OUT);
        assert!(Object::ALL.iter().all(|o| !all.contains(o)), "the base objects are not in the library");
    }

    #[test]
    fn every_object_fits_both_grippers_and_its_top_lets_the_fingers_pass() {
        for o in Object::ALL.into_iter().chain(Object::library()) {
            let [x, y, z] = o.shape().half_extents();
            // Closed across the narrow side: under the Panda's 8 cm opening with room to spare; centres at least
            // as high as the experts' lowest grasp point (2.2 cm above the floor).
            assert!(x.min(y) <= 0.028, "{} is {:.3} m across its narrow side", o.name(), 2.0 * x.min(y));
            assert!(x.max(y) <= 0.036 && (0.024..=0.056).contains(&z), "{} is out of size", o.name());
            if let Some(top) = o.top() {
                let [tx, ty, tz] = top.half_extents();
                assert!(tx.max(ty) < x.min(y) && tz <= 0.015, "{}'s top is too large", o.name());
            }
        }
    }

    #[test]
    fn an_environment_seed_draws_four_distinct_objects_of_its_split() {
        for seed in 0..50 {
            let train = environment_objects(Split::Train, seed);
            assert_eq!(train, environment_objects(Split::Train, seed));
            assert!(train.iter().all(|o| !o.held_out()));
            let mut distinct = train.to_vec();
            distinct.sort();
            distinct.dedup();
            assert_eq!(distinct.len(), 4);
            let mut held = environment_objects(Split::HeldOut, seed).to_vec();
            held.sort();
            assert_eq!(held, split_objects(Split::HeldOut));
        }
        assert_ne!(environment_objects(Split::Train, 1), environment_objects(Split::Train, 2));
    }
}
