//! Cameras: pinhole perspective and orthographic, generating one jittered ray per sample.
//! A camera is placed in f64, as a scene far from the origin needs: its rays are made in
//! f32 once it has been moved into the frame the scene is rendered in, near the scene.

use crate::error::{Error, Result};
use glam::{DVec3, Vec3};

/// How the camera projects.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Projection {
    /// Pinhole with a vertical field of view in degrees.
    Perspective {
        /// Vertical field of view, degrees.
        vfov_deg: f32,
    },
    /// Parallel rays; `height` is the world-space height of the view.
    Orthographic {
        /// World-space view height.
        height: f32,
    },
}

/// A camera placed in the scene's space, in f64 (so that a camera far from the origin
/// frames what is near it as exactly as one at the origin).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    /// Eye position.
    pub eye: DVec3,
    /// The point looked at.
    pub look_at: DVec3,
    /// Approximate up direction.
    pub up: Vec3,
    /// Projection.
    pub projection: Projection,
}

/// The camera reduced to what ray generation needs, for `width × height` pixels. The
/// shader receives the same numbers (`FrameUniforms`), so CPU and GPU rays agree.
#[derive(Clone, Copy, Debug)]
pub struct RayGen {
    /// Eye position.
    pub eye_ws: Vec3,
    /// Image-plane x axis, scaled to half the view width.
    pub right_ws: Vec3,
    /// Image-plane y axis, scaled to half the view height.
    pub up_ws: Vec3,
    /// View direction (unit).
    pub forward_ws: Vec3,
    /// True for orthographic.
    pub orthographic: bool,
}

impl Camera {
    /// Checks the camera is well-defined: finite, eye ≠ target, up not along the view
    /// ([`Error::Settings`] saying what is wrong).
    pub fn validate(&self) -> Result<()> {
        let finite = self.eye.is_finite() && self.look_at.is_finite() && self.up.is_finite();
        if !finite {
            return Err(Error::settings("camera has a non-finite coordinate"));
        }
        let forward = self.look_at - self.eye;
        if forward.length_squared() == 0.0 {
            return Err(Error::settings("camera eye and look_at are the same point"));
        }
        if forward.normalize().cross(self.up.as_dvec3()).length_squared() < 1e-12 {
            return Err(Error::settings("camera up is parallel to the view direction"));
        }
        match self.projection {
            Projection::Perspective { vfov_deg } if !(vfov_deg > 0.0 && vfov_deg < 180.0) => {
                Err(Error::settings(format!("camera fov must be in (0, 180) degrees, got {vfov_deg}")))
            }
            Projection::Orthographic { height } if !(height > 0.0 && height.is_finite()) => {
                Err(Error::settings(format!("camera height must be positive, got {height}")))
            }
            _ => Ok(()),
        }
    }

    /// Checks what [`Camera::ray_gen`] makes of the camera in f32: the eye and the target
    /// still apart, the view still across `up`. A camera moved into the frame the scene
    /// is rendered in is checked again this way; one far from that frame may fail it.
    pub(crate) fn validate_f32(&self) -> Result<()> {
        let (eye, look_at) = (self.eye.as_vec3(), self.look_at.as_vec3());
        let forward = look_at - eye;
        if !(forward.length_squared() > 0.0 && forward.length_squared().is_finite()) {
            return Err(Error::settings(
                "camera eye and look_at are the same point in f32, where the rays are made: move them apart",
            ));
        }
        if forward.normalize().cross(self.up).length_squared() < 1e-12 {
            return Err(Error::settings("camera up is parallel to the view direction"));
        }
        Ok(())
    }

    /// The ray-generation frame for an image of the given size.
    /// The eye and the target are rounded to f32 first: the camera is to be in the frame
    /// the scene is rendered in.
    pub fn ray_gen(&self, width: u32, height: u32) -> RayGen {
        let (eye, look_at) = (self.eye.as_vec3(), self.look_at.as_vec3());
        let forward = (look_at - eye).normalize();
        let right = forward.cross(self.up).normalize();
        let up = right.cross(forward);
        let aspect = width as f32 / height as f32;
        let (half_h, orthographic) = match self.projection {
            Projection::Perspective { vfov_deg } => ((0.5 * vfov_deg.to_radians()).tan(), false),
            Projection::Orthographic { height } => (0.5 * height, true),
        };
        RayGen { eye_ws: eye, right_ws: right * half_h * aspect, up_ws: up * half_h, forward_ws: forward, orthographic }
    }
}

impl RayGen {
    /// Ray through the image-plane position `(x, y)` in pixels (y down), e.g. pixel
    /// centre `(px + 0.5, py + 0.5)`. Returns origin and unit direction.
    pub fn ray(&self, x: f32, y: f32, width: u32, height: u32) -> (Vec3, Vec3) {
        let sx = 2.0 * x / width as f32 - 1.0;
        let sy = 1.0 - 2.0 * y / height as f32;
        if self.orthographic {
            (self.eye_ws + sx * self.right_ws + sy * self.up_ws, self.forward_ws)
        } else {
            let d = self.forward_ws + sx * self.right_ws + sy * self.up_ws;
            (self.eye_ws, d.normalize())
        }
    }
}
