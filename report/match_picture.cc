#include "report/match_picture.h"

#include <fmt/format.h>

#include <algorithm>

#include "report/html.h"

namespace hscloc {
namespace {

namespace fs = std::filesystem;

constexpr double kHeight = 260;
constexpr double kGap = 20;

std::string Photo(const fs::path& images_dir, const std::string& name, double x, double width) {
  const fs::path path = images_dir / name;
  if (images_dir.empty() || !fs::exists(path)) {
    return fmt::format("<rect x='{:.0f}' y='0' width='{:.0f}' height='{:.0f}' fill='#dde'/>", x,
                       width, kHeight);
  }
  return fmt::format(
      "<image href='{}' x='{:.0f}' y='0' width='{:.0f}' height='{:.0f}' "
      "preserveAspectRatio='none' opacity='0.8'/>",
      EscapeHtml(fs::absolute(path).string()), x, width, kHeight);
}

}  // namespace

std::string MatchPictureSvg(const LocalizationQuery& query, const PoseResult& result,
                            const Scene& scene, const fs::path& images_dir) {
  if (!result.success) return "";
  const LocalizationCandidate& best = result.candidates[result.best_candidate];
  const SceneImage& image = scene.images[best.image_index];
  const Camera& camera = scene.cameras.at(image.camera_id);
  const double left_scale = kHeight / query.camera.height;
  const double right_scale = kHeight / camera.height;
  const double left_width = query.camera.width * left_scale;
  const double right_width = camera.width * right_scale;
  std::string svg = fmt::format(
      "<svg xmlns='http://www.w3.org/2000/svg' width='{:.0f}' height='{:.0f}' "
      "font-family='sans-serif'><rect width='100%' height='100%' fill='#f4f4f4'/>",
      left_width + kGap + right_width, kHeight + 20);
  svg += Photo(images_dir, query.name, 0, left_width);
  svg += Photo(images_dir, image.name, left_width + kGap, right_width);
  for (size_t i = 0; i < result.match_points.size(); ++i) {
    const bool inlier = result.match_inliers[i] != 0;
    const Eigen::Vector2d keypoint =
        query.keypoints.row(result.match_keypoints[i]).transpose().cast<double>() * left_scale;
    const Eigen::Vector3d in_camera = image.cam_from_world * scene.points[result.match_points[i]];
    if (in_camera.z() <= 0) continue;
    // A pooled final pose also matches points of other retrieved images that this one may not
    // show.
    const Eigen::Vector2d in_image = camera.ImgFromPointInCam(in_camera);
    if (!camera.IsInside(in_image)) continue;
    const Eigen::Vector2d projected =
        in_image * right_scale + Eigen::Vector2d(left_width + kGap, 0);
    const char* kind = inlier ? "inlier" : "outlier";
    const char* color = inlier ? "#1a9850" : "#d73027";
    if (inlier && i % 3 == 0) {
      svg += fmt::format(
          "<line x1='{:.1f}' y1='{:.1f}' x2='{:.1f}' y2='{:.1f}' stroke='#1a9850' "
          "stroke-opacity='0.5'/>",
          keypoint.x(), keypoint.y(), projected.x(), projected.y());
    }
    for (const Eigen::Vector2d& at : {keypoint, projected}) {
      svg += fmt::format("<circle class='{}' cx='{:.1f}' cy='{:.1f}' r='2' fill='{}'/>", kind,
                         at.x(), at.y(), color);
    }
  }
  svg += fmt::format(
      "<text x='4' y='{:.0f}' font-size='12'>{}: {} inliers (green) of {} matches from {} "
      "retrieved image(s), shown in {}</text></svg>\n",
      kHeight + 15, EscapeHtml(query.name), result.num_inliers, result.match_points.size(),
      std::max(1, result.num_pooled_candidates), EscapeHtml(image.name));
  return svg;
}

}  // namespace hscloc
