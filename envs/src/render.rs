//! A CPU ray caster over the physics shapes (every drawn body collides, the arm's links
//! included), so episodes can be looked at without a GPU, EGL or a display.
//!
//! Images are RGB, 8 bits per channel, row-major with row 0 at the TOP of the picture (the
//! convention of numpy image arrays, PIL and imageio). Colours come from each collider's user
//! data (see [`crate::world::colour_code`]); shading is Lambertian with one directional light
//! and hard shadows.

use nalgebra::Vector3;
use rapier3d::parry::query::Ray;
use rapier3d::prelude::{Pose, SharedShape, Vector};

use crate::env::Env;
use crate::error::{EnvError, Result};
use crate::scene::Scene;

/// An RGB image, row 0 at the top.
#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    pub width: usize,
    pub height: usize,
    /// `height * width * 3` bytes.
    pub data: Vec<u8>,
}

/// A pinhole camera.
#[derive(Clone, Debug, PartialEq)]
pub struct Camera {
    pub eye: Vector3<f64>,
    pub target: Vector3<f64>,
    /// Vertical field of view (degrees).
    pub fov_y: f64,
}

impl Default for Camera {
    /// A three-quarter view of the table from the side opposite the robot.
    fn default() -> Self {
        Self { eye: Vector3::new(0.75, 0.62, 1.38), target: Vector3::new(-0.18, 0.0, 0.95), fov_y: 50.0 }
    }
}

struct Primitive {
    shape: SharedShape,
    pose: Pose,
    colour: [f32; 3],
    lo: [f32; 3],
    hi: [f32; 3],
}

fn colour_of(user_data: u128) -> [f32; 3] {
    if user_data & (1 << 32) != 0 {
        let c = user_data as u32;
        [((c >> 16) & 255) as f32 / 255.0, ((c >> 8) & 255) as f32 / 255.0, (c & 255) as f32 / 255.0]
    } else {
        [0.7, 0.7, 0.7]
    }
}

fn primitive(shape: SharedShape, pose: Pose, colour: [f32; 3]) -> Primitive {
    let aabb = shape.compute_aabb(&pose);
    Primitive {
        shape,
        pose,
        colour,
        lo: [aabb.mins.x, aabb.mins.y, aabb.mins.z],
        hi: [aabb.maxs.x, aabb.maxs.y, aabb.maxs.z],
    }
}

/// Slab test: does the ray enter the box before `max_t`?
fn hits_box(o: [f32; 3], inv: [f32; 3], lo: &[f32; 3], hi: &[f32; 3], max_t: f32) -> bool {
    let (mut t0, mut t1) = (0.0f32, max_t);
    for k in 0..3 {
        let a = (lo[k] - o[k]) * inv[k];
        let b = (hi[k] - o[k]) * inv[k];
        t0 = t0.max(a.min(b));
        t1 = t1.min(a.max(b));
    }
    t0 <= t1
}

fn cast(prims: &[Primitive], ray: &Ray, max_t: f32) -> Option<(f32, Vector, usize)> {
    let o = [ray.origin.x, ray.origin.y, ray.origin.z];
    let inv = [1.0 / ray.dir.x, 1.0 / ray.dir.y, 1.0 / ray.dir.z];
    let mut best: Option<(f32, Vector, usize)> = None;
    for (i, p) in prims.iter().enumerate() {
        let limit = best.map_or(max_t, |b| b.0);
        if !hits_box(o, inv, &p.lo, &p.hi, limit) {
            continue;
        }
        if let Some(hit) = p.shape.cast_ray_and_get_normal(&p.pose, ray, limit, true) {
            if hit.time_of_impact < limit {
                best = Some((hit.time_of_impact, hit.normal, i));
            }
        }
    }
    best
}

/// Render the scene as the camera sees it.
pub fn render_scene(scene: &mut Scene, camera: &Camera, width: usize, height: usize) -> Result<Image> {
    if width == 0 || height == 0 || width > 4096 || height > 4096 {
        return Err(EnvError::InvalidConfig(format!("image size {width}x{height} must be within 1..=4096")));
    }
    let prims: Vec<Primitive> = scene
        .world
        .colliders
        .iter()
        .map(|(_, c)| primitive(c.shared_shape().clone(), *c.position(), colour_of(c.user_data)))
        .collect();
    let forward = (camera.target - camera.eye).normalize();
    let right = forward.cross(&Vector3::z()).normalize();
    let up = right.cross(&forward);
    let tan = libm::tan(camera.fov_y.to_radians() * 0.5);
    let aspect = width as f64 / height as f64;
    let light = Vector::new(0.35, 0.25, 1.0).normalize();
    let eye = Vector::new(camera.eye.x as f32, camera.eye.y as f32, camera.eye.z as f32);
    let mut data = vec![0u8; width * height * 3];
    for row in 0..height {
        for col in 0..width {
            let u = ((col as f64 + 0.5) / width as f64 * 2.0 - 1.0) * tan * aspect;
            let v = (1.0 - (row as f64 + 0.5) / height as f64 * 2.0) * tan;
            let d = (forward + right * u + up * v).normalize();
            let ray = Ray::new(eye, Vector::new(d.x as f32, d.y as f32, d.z as f32));
            let rgb = match cast(&prims, &ray, 20.0) {
                Some((t, n, i)) => {
                    let n = if n.dot(ray.dir) > 0.0 { -n } else { n };
                    let p = ray.point_at(t) + n * 1e-3;
                    let lit = n.dot(light).max(0.0);
                    let shadow = lit > 0.0 && cast(&prims, &Ray::new(p, light), 5.0).is_some();
                    let k = 0.35 + if shadow { 0.0 } else { 0.65 * lit };
                    prims[i].colour.map(|c| c * k)
                }
                None => {
                    let s = 0.5 + 0.5 * d.z as f32;
                    [0.55 + 0.3 * s, 0.65 + 0.25 * s, 0.8 + 0.15 * s]
                }
            };
            let o = (row * width + col) * 3;
            for k in 0..3 {
                data[o + k] = (rgb[k].clamp(0.0, 1.0) * 255.0 + 0.5) as u8;
            }
        }
    }
    Ok(Image { width, height, data })
}

/// Write an image as PNG.
pub fn save_png(image: &Image, path: impl AsRef<std::path::Path>) -> Result<()> {
    let path = path.as_ref();
    let io = |e: &dyn std::fmt::Display| EnvError::Io(format!("{}: {e}", path.display()));
    let file = std::fs::File::create(path).map_err(|e| io(&e))?;
    let mut enc = png::Encoder::new(std::io::BufWriter::new(file), image.width as u32, image.height as u32);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    let mut writer = enc.write_header().map_err(|e| io(&e))?;
    writer.write_image_data(&image.data).map_err(|e| io(&e))?;
    Ok(())
}

impl Env {
    /// Render the current state from the default camera.
    pub fn render(&mut self, width: usize, height: usize) -> Result<Image> {
        self.render_from(&Camera::default(), width, height)
    }

    pub fn render_from(&mut self, camera: &Camera, width: usize, height: usize) -> Result<Image> {
        render_scene(self.scene_mut(), camera, width, height)
    }
}
