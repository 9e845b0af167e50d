#include "geometry/camera.h"

#include <Eigen/LU>
#include <array>
#include <cmath>
#include <limits>

#include "util/check.h"

namespace hscloc {
namespace {

struct CameraModelInfo {
  CameraModelId id;
  const char* name;
  size_t num_params;
  // 1 (f) or 2 (fx, fy). COLMAP orders every model as focal lengths, principal point, distortion.
  size_t num_focal_params;
};

constexpr std::array<CameraModelInfo, 11> kCameraModels = {{
    {CameraModelId::kSimplePinhole, "SIMPLE_PINHOLE", 3, 1},
    {CameraModelId::kPinhole, "PINHOLE", 4, 2},
    {CameraModelId::kSimpleRadial, "SIMPLE_RADIAL", 4, 1},
    {CameraModelId::kRadial, "RADIAL", 5, 1},
    {CameraModelId::kOpenCV, "OPENCV", 8, 2},
    {CameraModelId::kOpenCVFisheye, "OPENCV_FISHEYE", 8, 2},
    {CameraModelId::kFullOpenCV, "FULL_OPENCV", 12, 2},
    {CameraModelId::kFOV, "FOV", 5, 2},
    {CameraModelId::kSimpleRadialFisheye, "SIMPLE_RADIAL_FISHEYE", 4, 1},
    {CameraModelId::kRadialFisheye, "RADIAL_FISHEYE", 5, 1},
    {CameraModelId::kThinPrismFisheye, "THIN_PRISM_FISHEYE", 12, 2},
}};

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
const Eigen::Vector2d kNaN2(kNaN, kNaN);

constexpr int kMaxNewtonIterations = 50;
// A few ulps above the rounding noise of the residual, so a converged iteration always stops.
constexpr double kNewtonRelativeStep = 1e-14;
// Below this argument the truncated series of atan(x)/x, tan(x)/x and 2 tan(x/2)/x is exact in
// double precision (the first dropped term is of order x^4 < 1e-24).
constexpr double kSeriesThreshold = 1e-6;

const CameraModelInfo* FindModel(CameraModelId model_id) {
  for (const CameraModelInfo& info : kCameraModels) {
    if (info.id == model_id) return &info;
  }
  return nullptr;
}

const CameraModelInfo& ModelInfo(CameraModelId model_id) {
  const CameraModelInfo* info = FindModel(model_id);
  if (info == nullptr) {
    ThrowInvalidArgument("unknown camera model id {}", static_cast<int>(model_id));
  }
  return *info;
}

std::string KnownModelNames() {
  std::string names;
  for (const CameraModelInfo& info : kCameraModels) {
    if (!names.empty()) names += ", ";
    names += info.name;
  }
  return names;
}

double AtanOverX(double x) {
  return std::abs(x) < kSeriesThreshold ? 1.0 - x * x / 3.0 : std::atan(x) / x;
}

double TanOverX(double x) {
  return std::abs(x) < kSeriesThreshold ? 1.0 + x * x / 3.0 : std::tan(x) / x;
}

double TwiceTanHalfOverX(double x) {
  return std::abs(x) < kSeriesThreshold ? 1.0 + x * x / 12.0 : 2.0 * std::tan(x / 2.0) / x;
}

// t (1 + c0 t^2 + c1 t^4 + c2 t^6 + c3 t^8): the radial map of the purely radial models, with t
// the undistorted radius (SIMPLE_RADIAL, RADIAL) or the angle from the axis (the fisheyes).
struct OddPolynomial {
  std::array<double, 4> c{};

  double Factor(double t2) const {
    return 1.0 + t2 * (c[0] + t2 * (c[1] + t2 * (c[2] + t2 * c[3])));
  }
  double Derivative(double t) const {
    const double t2 = t * t;
    return 1.0 + t2 * (3.0 * c[0] + t2 * (5.0 * c[1] + t2 * (7.0 * c[2] + t2 * 9.0 * c[3])));
  }
  // The root on the increasing branch through the origin. Starting at t = value, Newton moves
  // monotonically towards that root for a concave or convex map; a non-positive slope means the
  // value lies beyond the fold, where the map has no inverse.
  double Invert(double value) const {
    double t = value;
    for (int i = 0; i < kMaxNewtonIterations; ++i) {
      const double slope = Derivative(t);
      if (!(slope > 0.0)) return kNaN;
      const double step = (t * Factor(t * t) - value) / slope;
      t -= step;
      if (std::abs(step) <= kNewtonRelativeStep * std::abs(t)) return t;
    }
    return kNaN;
  }
};

// Radial (rational for FULL_OPENCV), decentering and thin-prism distortion as OpenCV and COLMAP
// parametrize them (Brown 1966; Weng et al., TPAMI 1992).
struct BrownConrady {
  std::array<double, 4> numerator{};    // coefficients of r^2, r^4, r^6, r^8
  std::array<double, 3> denominator{};  // coefficients of r^2, r^4, r^6
  double p1 = 0.0;
  double p2 = 0.0;
  double sx1 = 0.0;
  double sy1 = 0.0;

  Eigen::Vector2d Apply(const Eigen::Vector2d& x) const {
    const double u = x.x();
    const double v = x.y();
    const double r2 = u * u + v * v;
    const double radial = Numerator(r2) / Denominator(r2);
    return {u * radial + 2.0 * p1 * u * v + p2 * (r2 + 2.0 * u * u) + sx1 * r2,
            v * radial + 2.0 * p2 * u * v + p1 * (r2 + 2.0 * v * v) + sy1 * r2};
  }

  Eigen::Matrix2d Jacobian(const Eigen::Vector2d& x) const {
    const double u = x.x();
    const double v = x.y();
    const double r2 = u * u + v * v;
    const double n = Numerator(r2);
    const double d = Denominator(r2);
    const double n_prime =
        numerator[0] +
        r2 * (2.0 * numerator[1] + r2 * (3.0 * numerator[2] + r2 * 4.0 * numerator[3]));
    const double d_prime = denominator[0] + r2 * (2.0 * denominator[1] + r2 * 3.0 * denominator[2]);
    const double radial = n / d;
    // d(radial)/d(r^2); d(r^2)/du = 2u.
    const double radial_prime = (n_prime * d - n * d_prime) / (d * d);
    Eigen::Matrix2d jacobian;
    jacobian(0, 0) =
        radial + 2.0 * u * u * radial_prime + 2.0 * p1 * v + 6.0 * p2 * u + 2.0 * sx1 * u;
    jacobian(0, 1) = 2.0 * u * v * radial_prime + 2.0 * p1 * u + 2.0 * p2 * v + 2.0 * sx1 * v;
    jacobian(1, 0) = 2.0 * u * v * radial_prime + 2.0 * p2 * v + 2.0 * p1 * u + 2.0 * sy1 * u;
    jacobian(1, 1) =
        radial + 2.0 * v * v * radial_prime + 2.0 * p2 * u + 6.0 * p1 * v + 2.0 * sy1 * v;
    return jacobian;
  }

  // Newton from the distorted point itself, which for realistic distortion lies in the basin of
  // the undistorted one; a singular or orientation-flipping Jacobian means a fold.
  Eigen::Vector2d Invert(const Eigen::Vector2d& distorted) const {
    Eigen::Vector2d x = distorted;
    for (int i = 0; i < kMaxNewtonIterations; ++i) {
      const Eigen::Matrix2d jacobian = Jacobian(x);
      if (!(jacobian.determinant() > 0.0)) return kNaN2;
      const Eigen::Vector2d step = jacobian.inverse() * (Apply(x) - distorted);
      x -= step;
      if (step.norm() <= kNewtonRelativeStep * x.norm()) return x;
    }
    return kNaN2;
  }

 private:
  double Numerator(double r2) const {
    return 1.0 +
           r2 * (numerator[0] + r2 * (numerator[1] + r2 * (numerator[2] + r2 * numerator[3])));
  }
  double Denominator(double r2) const {
    return 1.0 + r2 * (denominator[0] + r2 * (denominator[1] + r2 * denominator[2]));
  }
};

OddPolynomial RadialPolynomialOf(CameraModelId model_id, const double* extra) {
  switch (model_id) {
    case CameraModelId::kSimpleRadial:
    case CameraModelId::kSimpleRadialFisheye:
      return {{extra[0], 0.0, 0.0, 0.0}};
    case CameraModelId::kRadial:
    case CameraModelId::kRadialFisheye:
      return {{extra[0], extra[1], 0.0, 0.0}};
    case CameraModelId::kOpenCVFisheye:
      return {{extra[0], extra[1], extra[2], extra[3]}};
    default:
      return {};
  }
}

BrownConrady BrownConradyOf(CameraModelId model_id, const double* extra) {
  BrownConrady distortion;
  distortion.numerator = {extra[0], extra[1], 0.0, 0.0};
  distortion.p1 = extra[2];
  distortion.p2 = extra[3];
  if (model_id == CameraModelId::kFullOpenCV) {
    distortion.numerator[2] = extra[4];
    distortion.denominator = {extra[5], extra[6], extra[7]};
  } else if (model_id == CameraModelId::kThinPrismFisheye) {
    distortion.numerator[2] = extra[4];
    distortion.numerator[3] = extra[5];
    distortion.sx1 = extra[6];
    distortion.sy1 = extra[7];
  }
  return distortion;
}

// Perspective normalized coordinates (radius tan(theta)) -> equidistant ones (radius theta).
Eigen::Vector2d EquidistantFromNormalized(const Eigen::Vector2d& normalized) {
  return normalized * AtanOverX(normalized.norm());
}

Eigen::Vector2d NormalizedFromEquidistant(const Eigen::Vector2d& equidistant) {
  const double theta = equidistant.norm();
  if (theta >= M_PI / 2.0) return kNaN2;
  return equidistant * TanOverX(theta);
}

// Applies the inverse of a radial map to the radius only; the direction is unchanged.
Eigen::Vector2d InvertRadially(const OddPolynomial& polynomial, const Eigen::Vector2d& distorted) {
  const double distorted_radius = distorted.norm();
  if (distorted_radius == 0.0) return distorted;
  return distorted * (polynomial.Invert(distorted_radius) / distorted_radius);
}

// FOV model (Devernay and Faugeras, MVA 2001): r_d = atan(2 r tan(omega / 2)) / omega, written
// as a product of factors that are each smooth through r = 0 and omega = 0. COLMAP 3.8 instead
// switches to a series below omega = 0.01 whose omega^2 terms have the wrong sign in this
// direction, so for such small omega it does not invert its own undistortion.
Eigen::Vector2d FovDistort(double omega, const Eigen::Vector2d& normalized) {
  const double z = normalized.norm() * TwiceTanHalfOverX(omega) * omega;
  return normalized * (AtanOverX(z) * TwiceTanHalfOverX(omega));
}

Eigen::Vector2d FovUndistort(double omega, const Eigen::Vector2d& distorted) {
  const double angle = distorted.norm() * std::abs(omega);
  if (angle >= M_PI / 2.0) return kNaN2;
  return distorted * (TanOverX(angle) / TwiceTanHalfOverX(omega));
}

// Normalized -> distorted normalized coordinates.
Eigen::Vector2d Distort(CameraModelId model_id, const double* extra,
                        const Eigen::Vector2d& normalized) {
  switch (model_id) {
    case CameraModelId::kSimplePinhole:
    case CameraModelId::kPinhole:
      return normalized;
    case CameraModelId::kSimpleRadial:
    case CameraModelId::kRadial:
      return normalized * RadialPolynomialOf(model_id, extra).Factor(normalized.squaredNorm());
    case CameraModelId::kOpenCVFisheye:
    case CameraModelId::kSimpleRadialFisheye:
    case CameraModelId::kRadialFisheye: {
      const Eigen::Vector2d equidistant = EquidistantFromNormalized(normalized);
      return equidistant * RadialPolynomialOf(model_id, extra).Factor(equidistant.squaredNorm());
    }
    case CameraModelId::kOpenCV:
    case CameraModelId::kFullOpenCV:
      return BrownConradyOf(model_id, extra).Apply(normalized);
    case CameraModelId::kThinPrismFisheye:
      return BrownConradyOf(model_id, extra).Apply(EquidistantFromNormalized(normalized));
    case CameraModelId::kFOV:
      return FovDistort(extra[0], normalized);
    case CameraModelId::kInvalid:
      break;
  }
  ThrowInvalidArgument("unknown camera model id {}", static_cast<int>(model_id));
}

// Distorted normalized -> normalized coordinates; NaN where the distortion has no inverse.
Eigen::Vector2d Undistort(CameraModelId model_id, const double* extra,
                          const Eigen::Vector2d& distorted) {
  switch (model_id) {
    case CameraModelId::kSimplePinhole:
    case CameraModelId::kPinhole:
      return distorted;
    case CameraModelId::kSimpleRadial:
    case CameraModelId::kRadial:
      return InvertRadially(RadialPolynomialOf(model_id, extra), distorted);
    case CameraModelId::kOpenCVFisheye:
    case CameraModelId::kSimpleRadialFisheye:
    case CameraModelId::kRadialFisheye:
      return NormalizedFromEquidistant(
          InvertRadially(RadialPolynomialOf(model_id, extra), distorted));
    case CameraModelId::kOpenCV:
    case CameraModelId::kFullOpenCV:
      return BrownConradyOf(model_id, extra).Invert(distorted);
    case CameraModelId::kThinPrismFisheye:
      return NormalizedFromEquidistant(BrownConradyOf(model_id, extra).Invert(distorted));
    case CameraModelId::kFOV:
      return FovUndistort(extra[0], distorted);
    case CameraModelId::kInvalid:
      break;
  }
  ThrowInvalidArgument("unknown camera model id {}", static_cast<int>(model_id));
}

struct Intrinsics {
  double fx;
  double fy;
  double cx;
  double cy;
  const double* extra;
};

// The one check on the projection path: it costs a comparison and keeps a camera that was never
// Check()ed from reading past its parameters.
Intrinsics SplitParams(const Camera& camera) {
  const CameraModelInfo& info = ModelInfo(camera.model_id);
  THROW_CHECK_MSG(camera.params.size() == info.num_params, "camera {}: {} takes {} params, got {}",
                  camera.camera_id, info.name, info.num_params, camera.params.size());
  const double* params = camera.params.data();
  const size_t num_focal = info.num_focal_params;
  return {params[0], params[num_focal - 1], params[num_focal], params[num_focal + 1],
          params + num_focal + 2};
}

}  // namespace

bool IsKnownCameraModelId(int model_id) {
  return FindModel(static_cast<CameraModelId>(model_id)) != nullptr;
}

std::string CameraModelName(CameraModelId model_id) { return ModelInfo(model_id).name; }

CameraModelId CameraModelIdFromName(const std::string& name) {
  for (const CameraModelInfo& info : kCameraModels) {
    if (name == info.name) return info.id;
  }
  ThrowInvalidArgument("unknown camera model name '{}' (known: {})", name, KnownModelNames());
}

size_t CameraModelNumParams(CameraModelId model_id) { return ModelInfo(model_id).num_params; }

void Camera::Check() const {
  const CameraModelInfo* info = FindModel(model_id);
  if (info == nullptr) {
    ThrowInvalidArgument("camera {}: model_id {} is not a COLMAP camera model (known: {})",
                         camera_id, static_cast<int>(model_id), KnownModelNames());
  }
  if (params.size() != info->num_params) {
    ThrowInvalidArgument("camera {}: params holds {} values, {} takes {}", camera_id, params.size(),
                         info->name, info->num_params);
  }
  if (width == 0) ThrowInvalidArgument("camera {}: width is 0", camera_id);
  if (height == 0) ThrowInvalidArgument("camera {}: height is 0", camera_id);
  for (size_t i = 0; i < params.size(); ++i) {
    if (!std::isfinite(params[i])) {
      ThrowInvalidArgument("camera {}: params[{}] is {}", camera_id, i, params[i]);
    }
  }
  for (size_t i = 0; i < info->num_focal_params; ++i) {
    if (!(params[i] > 0.0)) {
      ThrowInvalidArgument("camera {}: focal length params[{}] is {}, must be positive", camera_id,
                           i, params[i]);
    }
  }
}

Camera Camera::FromModelName(camera_t camera_id, const std::string& model_name, uint64_t width,
                             uint64_t height, std::vector<double> params) {
  Camera camera;
  camera.camera_id = camera_id;
  camera.model_id = CameraModelIdFromName(model_name);
  camera.width = width;
  camera.height = height;
  camera.params = std::move(params);
  camera.Check();
  return camera;
}

double Camera::MeanFocalLength() const {
  const Intrinsics intrinsics = SplitParams(*this);
  return 0.5 * (intrinsics.fx + intrinsics.fy);
}

Eigen::Vector2d Camera::ImgFromCam(const Eigen::Vector2d& normalized) const {
  const Intrinsics intrinsics = SplitParams(*this);
  const Eigen::Vector2d distorted = Distort(model_id, intrinsics.extra, normalized);
  return {intrinsics.fx * distorted.x() + intrinsics.cx,
          intrinsics.fy * distorted.y() + intrinsics.cy};
}

Eigen::Vector2d Camera::CamFromImg(const Eigen::Vector2d& pixel) const {
  const Intrinsics intrinsics = SplitParams(*this);
  const Eigen::Vector2d distorted((pixel.x() - intrinsics.cx) / intrinsics.fx,
                                  (pixel.y() - intrinsics.cy) / intrinsics.fy);
  return Undistort(model_id, intrinsics.extra, distorted);
}

}  // namespace hscloc
