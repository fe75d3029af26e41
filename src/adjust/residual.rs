//! One residual-block abstraction for every observation type of the adjustment: image
//! points (collinearity), object-point priors (control), POS centre and attitude priors
//! and LiDAR point-to-plane distances. Each block is whitened by its a-priori σ so that
//! the solver sees unit-weight residuals, and reports its Jacobians with respect to the
//! three kinds of parameter blocks (exterior orientation, interior orientation, object
//! point) whichever it touches.

use crate::geometry::{project_with_jacobians, Camera, Pose};
use nalgebra::{Matrix3, Rotation3, SMatrix, Vector2, Vector3};

/// Current values of all unknowns, indexed densely (photo, camera, point index).
#[derive(Debug, Clone)]
pub(crate) struct State {
    pub poses: Vec<Pose>,
    pub cameras: Vec<Camera>,
    pub points: Vec<Vector3<f64>>,
    /// Shift of the LiDAR's datum from the block's (LiDAR minus block, m), when the
    /// adjustment estimates it; zero otherwise.
    pub lidar_shift: Vector3<f64>,
}

/// What a residual block measures.
#[derive(Debug, Clone)]
pub(crate) enum Kind {
    /// Image coordinates of an object point (tie or control), σ in pixels.
    Image { pixel: Vector2<f64>, sigma: f64 },
    /// Surveyed position of a control point; an axis with σ = +∞ carries no prior (a GCP
    /// of unknown height): its whitened residual and Jacobian row are zero.
    PointPrior {
        value: Vector3<f64>,
        sigma: Vector3<f64>,
    },
    /// POS projection centre.
    PosCenter {
        value: Vector3<f64>,
        sigma: Vector3<f64>,
    },
    /// POS attitude (world→camera rotation), σ per angle in radians; the rotation boxed,
    /// one a photo, as inline it was the size of every block.
    PosAttitude {
        rotation: Box<Matrix3<f64>>,
        sigma: f64,
    },
    /// Distance of an object point to a LiDAR plane n·X = d, times √weight. With a
    /// `camera` slot the block holds the LiDAR datum shift b there and the point X + b
    /// is on the plane: the LiDAR is X's surface displaced by its own datum error.
    Plane {
        normal: Vector3<f64>,
        d: f64,
        sqrt_weight: f64,
    },
    /// The LiDAR datum shift's prior: zero, σ per axis (m).
    LidarDatum { sigma: Vector3<f64> },
}

impl Kind {
    pub fn label(&self) -> &'static str {
        match self {
            Kind::Image { .. } => "image point",
            Kind::PointPrior { .. } => "control point prior",
            Kind::PosCenter { .. } => "POS centre",
            Kind::PosAttitude { .. } => "POS attitude",
            Kind::Plane { .. } => "LiDAR plane",
            Kind::LidarDatum { .. } => "LiDAR datum prior",
        }
    }

    /// The observation group of the variance components (report names).
    pub fn group(&self) -> &'static str {
        match self {
            Kind::Image { .. } => "image",
            Kind::PointPrior { .. } => "control",
            Kind::PosCenter { .. } => "pos_center",
            Kind::PosAttitude { .. } => "pos_attitude",
            Kind::Plane { .. } => "plane",
            Kind::LidarDatum { .. } => "lidar_datum",
        }
    }

    /// Which residual components are observations (a prior axis with σ = ∞ is none).
    pub fn known(&self) -> [bool; 3] {
        match self {
            Kind::Image { .. } => [true, true, false],
            Kind::Plane { .. } => [true, false, false],
            Kind::PointPrior { sigma, .. } | Kind::PosCenter { sigma, .. } => {
                [0, 1, 2].map(|k| sigma[k].is_finite())
            }
            Kind::PosAttitude { .. } | Kind::LidarDatum { .. } => [true; 3],
        }
    }

    /// Rows of the block's whitened residual (those of a prior axis with σ = ∞ included).
    pub fn rows(&self) -> usize {
        match self {
            Kind::Image { .. } => 2,
            Kind::Plane { .. } => 1,
            Kind::PointPrior { .. }
            | Kind::PosCenter { .. }
            | Kind::PosAttitude { .. }
            | Kind::LidarDatum { .. } => 3,
        }
    }

    /// Number of scalar observations of the block.
    pub fn dof(&self) -> usize {
        self.known().iter().filter(|&&k| k).count()
    }
}

/// A residual block and the parameter blocks it touches. One an observation: 72 bytes,
/// where `Option<usize>` indices and the attitude prior's rotation inline made 144.
#[derive(Debug, Clone)]
pub(crate) struct ResidualBlock {
    pub kind: Kind,
    photo: Slot,
    camera: Slot,
    point: Slot,
    /// False once rejected as a gross error.
    pub active: bool,
}

const _: () = assert!(std::mem::size_of::<ResidualBlock>() <= 72);

/// An optional index of a parameter block in four bytes (`u32::MAX` for none).
#[derive(Debug, Clone, Copy)]
struct Slot(u32);

impl Slot {
    fn new(i: Option<usize>) -> Self {
        match i {
            Some(i) => Slot(
                u32::try_from(i)
                    .ok()
                    .filter(|&i| i != u32::MAX)
                    .expect("parameter block index within u32"),
            ),
            None => Slot(u32::MAX),
        }
    }

    fn get(self) -> Option<usize> {
        (self.0 != u32::MAX).then_some(self.0 as usize)
    }
}

/// Whitened residual (first `dim` rows used) and Jacobians. Exterior orientation uses
/// the first six columns of `j_photo` (δθ left-multiplied, then δC, as `Pose::perturbed`);
/// `j_camera` has one column per interior parameter of `Camera::params`.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Eval {
    pub dim: usize,
    pub r: Vector3<f64>,
    pub j_photo: SMatrix<f64, 3, 9>,
    pub j_camera: SMatrix<f64, 3, 9>,
    pub j_point: Matrix3<f64>,
}

impl Eval {
    fn new(dim: usize) -> Self {
        Self {
            dim,
            r: Vector3::zeros(),
            j_photo: SMatrix::zeros(),
            j_camera: SMatrix::zeros(),
            j_point: Matrix3::zeros(),
        }
    }
    pub fn norm_sq(&self) -> f64 {
        self.r.norm_squared()
    }
}

/// Rotation vector of a rotation matrix (the inverse of `rotation_from_vector`).
pub(crate) fn rotation_vector(r: &Matrix3<f64>) -> Vector3<f64> {
    Rotation3::from_matrix_unchecked(*r).scaled_axis()
}

impl ResidualBlock {
    /// An active block of `kind` on the photo, camera slot and object point given.
    pub fn new(
        kind: Kind,
        photo: Option<usize>,
        camera: Option<usize>,
        point: Option<usize>,
    ) -> Self {
        Self {
            kind,
            photo: Slot::new(photo),
            camera: Slot::new(camera),
            point: Slot::new(point),
            active: true,
        }
    }

    pub fn photo(&self) -> Option<usize> {
        self.photo.get()
    }

    /// The camera, or for a LiDAR block the slot of the LiDAR datum shift.
    pub fn camera(&self) -> Option<usize> {
        self.camera.get()
    }

    pub fn point(&self) -> Option<usize> {
        self.point.get()
    }

    /// Residual and Jacobians at `state`; `None` when the block cannot be evaluated
    /// (object point behind the camera), which the solver treats as a missing observation.
    pub fn evaluate(&self, s: &State) -> Option<Eval> {
        let mut e = Eval::new(self.kind.rows());
        self.fill(s, &mut e)?;
        Some(e)
    }

    /// The whitened residual alone (rows beyond its dimension zero), as [`Self::evaluate`]
    /// computes it, without the Jacobians: what a trial step of the solver needs.
    pub fn residual(&self, s: &State) -> Option<Vector3<f64>> {
        match &self.kind {
            Kind::Image { pixel, sigma } => {
                let (ph, cam, pt) = (self.photo()?, self.camera()?, self.point()?);
                let xc = s.poses[ph].to_camera(&s.points[pt]);
                let p = s.cameras[cam].project_as_with_jacobian(&xc).ok()?;
                let r = (p - pixel) * (1.0 / sigma);
                Some(Vector3::new(r.x, r.y, 0.0))
            }
            Kind::PointPrior { value, sigma } => {
                Some((s.points[self.point()?] - value).component_div(sigma))
            }
            Kind::PosCenter { value, sigma } => {
                Some((s.poses[self.photo()?].center - value).component_div(sigma))
            }
            Kind::PosAttitude { rotation, sigma } => {
                let r = s.poses[self.photo()?].rotation;
                Some(rotation_vector(&(r * rotation.transpose())) / *sigma)
            }
            Kind::Plane {
                normal,
                d,
                sqrt_weight,
            } => {
                let mut x = s.points[self.point()?];
                if self.camera().is_some() {
                    x += s.lidar_shift;
                }
                Some(Vector3::new((normal.dot(&x) - d) * sqrt_weight, 0.0, 0.0))
            }
            Kind::LidarDatum { sigma } => Some(s.lidar_shift.component_div(sigma)),
        }
    }

    /// Writes the residual and Jacobians into `e`, zero and of the block's rows.
    fn fill(&self, s: &State, e: &mut Eval) -> Option<()> {
        match &self.kind {
            Kind::Image { pixel, sigma } => {
                let (ph, cam, pt) = (self.photo()?, self.camera()?, self.point()?);
                let (p, j) =
                    project_with_jacobians(&s.cameras[cam], &s.poses[ph], &s.points[pt]).ok()?;
                let w = 1.0 / sigma;
                let r = (p.pixel - pixel) * w;
                e.r = Vector3::new(r.x, r.y, 0.0);
                e.j_photo
                    .fixed_view_mut::<2, 6>(0, 0)
                    .copy_from(&(j.pose * w));
                e.j_camera
                    .fixed_view_mut::<2, 9>(0, 0)
                    .copy_from(&(j.intrinsics * w));
                e.j_point
                    .fixed_view_mut::<2, 3>(0, 0)
                    .copy_from(&(j.point * w));
                Some(())
            }
            Kind::PointPrior { value, sigma } => {
                let x = s.points[self.point()?];
                e.r = (x - value).component_div(sigma);
                e.j_point = Matrix3::from_diagonal(&sigma.map(|v| 1.0 / v));
                Some(())
            }
            Kind::PosCenter { value, sigma } => {
                let c = s.poses[self.photo()?].center;
                e.r = (c - value).component_div(sigma);
                e.j_photo
                    .fixed_view_mut::<3, 3>(0, 3)
                    .copy_from(&Matrix3::from_diagonal(&sigma.map(|v| 1.0 / v)));
                Some(())
            }
            Kind::PosAttitude { rotation, sigma } => {
                let r = s.poses[self.photo()?].rotation;
                // exp(δθ)·R·R₀ᵀ: to first order the residual moves by δθ itself.
                e.r = rotation_vector(&(r * rotation.transpose())) / *sigma;
                e.j_photo
                    .fixed_view_mut::<3, 3>(0, 0)
                    .copy_from(&(Matrix3::identity() / *sigma));
                Some(())
            }
            Kind::Plane {
                normal,
                d,
                sqrt_weight,
            } => {
                let mut x = s.points[self.point()?];
                let j = normal.transpose() * *sqrt_weight;
                if self.camera().is_some() {
                    x += s.lidar_shift;
                    e.j_camera.fixed_view_mut::<1, 3>(0, 0).copy_from(&j);
                }
                e.r.x = (normal.dot(&x) - d) * sqrt_weight;
                e.j_point.fixed_view_mut::<1, 3>(0, 0).copy_from(&j);
                Some(())
            }
            Kind::LidarDatum { sigma } => {
                e.r = s.lidar_shift.component_div(sigma);
                e.j_camera
                    .fixed_view_mut::<3, 3>(0, 0)
                    .copy_from(&Matrix3::from_diagonal(&sigma.map(|v| 1.0 / v)));
                Some(())
            }
        }
    }
}

/// Robust loss ρ(s) of the squared whitened residual norm s, as in Ceres.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Loss {
    /// Ordinary least squares.
    None,
    /// Huber with threshold `c` (whitened units): quadratic inside, linear outside.
    Huber(f64),
    /// Cauchy with scale `c`: redescending influence, for heavy gross-error rates.
    Cauchy(f64),
}

impl Loss {
    /// ρ(s) and the IRLS weight ρ'(s).
    pub fn rho(&self, s: f64) -> (f64, f64) {
        match *self {
            Loss::None => (s, 1.0),
            Loss::Huber(c) => {
                let c2 = c * c;
                if s <= c2 {
                    (s, 1.0)
                } else {
                    let r = s.sqrt();
                    (2.0 * c * r - c2, c / r)
                }
            }
            Loss::Cauchy(c) => {
                let c2 = c * c;
                (c2 * (1.0 + s / c2).ln(), 1.0 / (1.0 + s / c2))
            }
        }
    }
}
