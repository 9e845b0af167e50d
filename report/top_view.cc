#include "report/top_view.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <unordered_map>

#include "report/html.h"
#include "util/check.h"
#include "util/statistics.h"

namespace hscloc {
namespace {

constexpr double kMargin = 12;
constexpr double kTitleHeight = 28;
constexpr double kLegendRowHeight = 18;
constexpr double kMinWidth = 430;
constexpr const char* kSuccessColor = "#1a9850";
constexpr const char* kFailureColor = "#d73027";

// World -> the ground plane's (east, north), from the database cameras' up direction.
class GroundPlane {
 public:
  explicit GroundPlane(const std::vector<Rigid3d>& cams_from_world) {
    Eigen::Vector3d down = Eigen::Vector3d::Zero();
    for (const Rigid3d& cam_from_world : cams_from_world) {
      down += cam_from_world.rotation.conjugate() * Eigen::Vector3d::UnitY();
    }
    const Eigen::Vector3d up =
        down.norm() > 1e-9 ? Eigen::Vector3d(-down.normalized()) : Eigen::Vector3d::UnitZ();
    Eigen::Vector3d east = Eigen::Vector3d::UnitX() - up.x() * up;
    if (east.norm() < 0.5) east = Eigen::Vector3d::UnitY() - up.y() * up;
    east_ = east.normalized();
    north_ = up.cross(east_);
  }
  Eigen::Vector2d operator()(const Eigen::Vector3d& point_in_world) const {
    return {east_.dot(point_in_world), north_.dot(point_in_world)};
  }

 private:
  Eigen::Vector3d east_;
  Eigen::Vector3d north_;
};

// The view's extent on the ground plane and its mapping to SVG pixels (y down, north up).
struct ViewBox {
  Eigen::Vector2d min;
  Eigen::Vector2d max;
  double scale_px = 1;  // pixels per world unit
  Eigen::Vector2d origin_px;

  bool Contains(const Eigen::Vector2d& p) const {
    return (p.array() >= min.array()).all() && (p.array() <= max.array()).all();
  }
  Eigen::Vector2d ToPixels(const Eigen::Vector2d& p) const {
    const Eigen::Vector2d clamped = p.cwiseMax(min).cwiseMin(max);
    return {origin_px.x() + (clamped.x() - min.x()) * scale_px,
            origin_px.y() + (max.y() - clamped.y()) * scale_px};
  }
  double WidthPx() const { return (max.x() - min.x()) * scale_px; }
  double HeightPx() const { return (max.y() - min.y()) * scale_px; }
};

ViewBox FitView(const std::vector<Eigen::Vector2d>& cameras,
                const std::vector<Eigen::Vector2d>& points, const TopViewOptions& options) {
  ViewBox view;
  view.min = Eigen::Vector2d::Constant(std::numeric_limits<double>::infinity());
  view.max = -view.min;
  for (const Eigen::Vector2d& camera : cameras) {
    view.min = view.min.cwiseMin(camera);
    view.max = view.max.cwiseMax(camera);
  }
  if (!points.empty()) {
    for (int axis = 0; axis < 2; ++axis) {
      std::vector<double> values;
      for (const Eigen::Vector2d& point : points) values.push_back(point[axis]);
      view.min[axis] = std::min(view.min[axis], Percentile(values, options.point_outlier_fraction));
      view.max[axis] =
          std::max(view.max[axis], Percentile(values, 1 - options.point_outlier_fraction));
    }
  }
  if (!view.min.allFinite()) view.min = view.max = Eigen::Vector2d::Zero();
  const double extent = std::max({view.max.x() - view.min.x(), view.max.y() - view.min.y(), 1.0});
  const Eigen::Vector2d padding = Eigen::Vector2d::Constant(0.04 * extent);
  view.min -= padding;
  view.max += padding;
  view.scale_px = options.map_size_px / (1.08 * extent);
  view.origin_px = {kMargin, kTitleHeight};
  return view;
}

// 1, 2 or 5 times a power of ten: the longest such length not over `limit`.
double RoundLength(double limit) {
  const double power = std::pow(10.0, std::floor(std::log10(limit)));
  for (const double factor : {5.0, 2.0}) {
    if (factor * power <= limit) return factor * power;
  }
  return power;
}

std::string Cross(const Eigen::Vector2d& at, double half, const std::string& title) {
  return fmt::format(
      "<path class='query-failure' d='M{0:.1f},{1:.1f}L{2:.1f},{3:.1f}M{0:.1f},{3:.1f}L{2:.1f},"
      "{1:.1f}' stroke='{4}' stroke-width='2'><title>{5}</title></path>\n",
      at.x() - half, at.y() - half, at.x() + half, at.y() + half, kFailureColor, title);
}

struct QueryCounts {
  size_t localized = 0;
  size_t failed = 0;
};

std::string DrawQueries(const std::vector<TopViewQuery>& queries, const GroundPlane& plane,
                        const ViewBox& view, const PoseThreshold& threshold, QueryCounts& counts) {
  std::string lines;
  std::string markers;
  for (const TopViewQuery& query : queries) {
    const Eigen::Vector2d truth =
        view.ToPixels(plane(CameraCenterInWorld(query.true_cam_from_world)));
    std::string title = EscapeHtml(query.name);
    bool success = false;
    if (query.estimated_cam_from_world.has_value()) {
      const Rigid3d& estimate = *query.estimated_cam_from_world;
      const double position = PositionError(estimate, query.true_cam_from_world);
      const double rotation_deg = RotationErrorDeg(estimate, query.true_cam_from_world);
      success = position <= threshold.position && rotation_deg <= threshold.rotation_deg;
      title += fmt::format(": {:.3g} m, {:.3g} deg", position, rotation_deg);
      const Eigen::Vector2d at = view.ToPixels(plane(CameraCenterInWorld(estimate)));
      const char* color = success ? kSuccessColor : kFailureColor;
      lines += fmt::format(
          "<line class='query-error' x1='{:.1f}' y1='{:.1f}' x2='{:.1f}' y2='{:.1f}' stroke='{}' "
          "stroke-width='1.5'/>\n",
          truth.x(), truth.y(), at.x(), at.y(), color);
      markers += fmt::format(
          "<circle class='query-estimate' cx='{:.1f}' cy='{:.1f}' r='2.5' fill='{}'><title>{}"
          "</title></circle>\n",
          at.x(), at.y(), color, title);
    } else {
      title += ": not localized";
    }
    markers += fmt::format(
        "<circle class='query-truth' cx='{:.1f}' cy='{:.1f}' r='3.5' fill='none' stroke='#000'>"
        "<title>{}</title></circle>\n",
        truth.x(), truth.y(), title);
    if (!success) markers += Cross(truth, 4, title);
    ++(success ? counts.localized : counts.failed);
  }
  return lines + markers;
}

std::string DrawScaleBar(const ViewBox& view, double y) {
  const double length = RoundLength((view.max.x() - view.min.x()) / 4);
  const double x = view.origin_px.x();
  const double width = length * view.scale_px;
  return fmt::format(
      "<g class='scale-bar'><path d='M{0:.1f},{1:.1f}v5h{2:.1f}v-5' fill='none' stroke='#000'/>"
      "<text x='{3:.1f}' y='{4:.1f}' font-size='11'>{5:g} m</text></g>\n",
      x, y - 5, width, x + width + 6, y + 1, length);
}

std::string DrawLegend(double y, size_t points_shown, size_t num_points, size_t num_cameras,
                       const QueryCounts& counts, const PoseThreshold& threshold) {
  const std::string within =
      fmt::format("({:g} m, {:g} deg)", threshold.position, threshold.rotation_deg);
  const std::vector<std::pair<std::string, std::string>> rows = {
      {"<circle cx='6' cy='-4' r='1.5' fill='#9a9a9a'/>",
       fmt::format("map points ({} of {} drawn)", points_shown, num_points)},
      {"<rect x='3' y='-7' width='6' height='6' fill='#4575b4'/>",
       fmt::format("database cameras ({})", num_cameras)},
      {"<circle cx='6' cy='-4' r='3.5' fill='none' stroke='#000'/>",
       "query camera, ground truth (line to its estimate)"},
      {fmt::format("<circle cx='6' cy='-4' r='2.5' fill='{}'/>", kSuccessColor),
       fmt::format("estimate within {} ({})", within, counts.localized)},
      {fmt::format("<path d='M2,-8L10,0M2,0L10,-8' stroke='{}' stroke-width='2'/>", kFailureColor),
       fmt::format("failure: no estimate, or outside {} ({})", within, counts.failed)}};
  std::string svg = "<g class='legend' font-size='11'>\n";
  for (size_t i = 0; i < rows.size(); ++i) {
    svg +=
        fmt::format("<g transform='translate({:.1f},{:.1f})'>{}<text x='16' y='0'>{}</text></g>\n",
                    kMargin, y + i * kLegendRowHeight, rows[i].first, EscapeHtml(rows[i].second));
  }
  return svg + "</g>\n";
}

}  // namespace

void TopViewOptions::Check() const {
  THROW_CHECK_MSG(map_size_px >= 50, "TopViewOptions.map_size_px = {} (>= 50)", map_size_px);
  THROW_CHECK_MSG(max_points >= 1, "TopViewOptions.max_points = {} (>= 1)", max_points);
  THROW_CHECK_MSG(success_threshold.position > 0 && success_threshold.rotation_deg > 0,
                  "TopViewOptions.success_threshold = ({} m, {} deg) (positive)",
                  success_threshold.position, success_threshold.rotation_deg);
  THROW_CHECK_MSG(point_outlier_fraction >= 0 && point_outlier_fraction < 0.5,
                  "TopViewOptions.point_outlier_fraction = {} ([0, 0.5))", point_outlier_fraction);
}

TopViewContent TopViewOf(const Scene& scene, const std::vector<NamedPose>& ground_truth,
                         const std::vector<NamedPose>& estimates) {
  TopViewContent content;
  content.points_in_world = scene.points;
  for (const SceneImage& image : scene.images) {
    content.database_cams_from_world.push_back(image.cam_from_world);
  }
  std::unordered_map<std::string, size_t> query_of_basename;
  for (const NamedPose& truth : ground_truth) {
    query_of_basename[ImageBasename(truth.name)] = content.queries.size();
    content.queries.push_back({truth.name, truth.cam_from_world, std::nullopt});
  }
  for (const NamedPose& estimate : estimates) {
    const auto query = query_of_basename.find(ImageBasename(estimate.name));
    if (query == query_of_basename.end()) {
      ThrowInvalidArgument("top view: the estimate '{}' is of no ground-truth query",
                           estimate.name);
    }
    content.queries[query->second].estimated_cam_from_world = estimate.cam_from_world;
  }
  return content;
}

std::string TopViewSvg(const TopViewContent& content, const TopViewOptions& options) {
  options.Check();
  const GroundPlane plane(content.database_cams_from_world);
  std::vector<Eigen::Vector2d> cameras;
  for (const Rigid3d& cam_from_world : content.database_cams_from_world) {
    cameras.push_back(plane(CameraCenterInWorld(cam_from_world)));
  }
  const size_t num_database_cameras = cameras.size();
  for (const TopViewQuery& query : content.queries) {
    cameras.push_back(plane(CameraCenterInWorld(query.true_cam_from_world)));
  }
  const size_t stride =
      (content.points_in_world.size() + options.max_points - 1) / options.max_points;
  std::vector<Eigen::Vector2d> points;
  for (size_t i = 0; i < content.points_in_world.size(); i += std::max<size_t>(stride, 1)) {
    points.push_back(plane(content.points_in_world[i]));
  }
  const ViewBox view = FitView(cameras, points, options);

  std::string body;
  size_t points_shown = 0;
  for (const Eigen::Vector2d& point : points) {
    if (!view.Contains(point)) continue;
    const Eigen::Vector2d at = view.ToPixels(point);
    body += fmt::format("<circle class='point' cx='{:.1f}' cy='{:.1f}' r='1' fill='#9a9a9a'/>\n",
                        at.x(), at.y());
    ++points_shown;
  }
  for (size_t i = 0; i < num_database_cameras; ++i) {
    const Eigen::Vector2d at = view.ToPixels(cameras[i]);
    body += fmt::format(
        "<rect class='database-camera' x='{:.1f}' y='{:.1f}' width='4' height='4' "
        "fill='#4575b4'/>\n",
        at.x() - 2, at.y() - 2);
  }
  QueryCounts counts;
  body += DrawQueries(content.queries, plane, view, options.success_threshold, counts);

  const double map_bottom = view.origin_px.y() + view.HeightPx();
  const double width = std::max(kMinWidth, view.WidthPx() + 2 * kMargin);
  const double height = map_bottom + 30 + 5 * kLegendRowHeight + kMargin;
  return fmt::format(
             "<svg xmlns='http://www.w3.org/2000/svg' width='{:.0f}' height='{:.0f}' "
             "font-family='sans-serif'>\n<rect width='100%' height='100%' fill='white'/>\n"
             "<text x='{}' y='19' font-size='15'>{}</text>\n"
             "<rect x='{:.1f}' y='{:.1f}' width='{:.1f}' height='{:.1f}' fill='#fbfbf8' "
             "stroke='#bbb'/>\n",
             width, height, kMargin, EscapeHtml(options.title), view.origin_px.x(),
             view.origin_px.y(), view.WidthPx(), view.HeightPx()) +
         body + DrawScaleBar(view, map_bottom + 18) +
         DrawLegend(map_bottom + 40, points_shown, content.points_in_world.size(),
                    num_database_cameras, counts, options.success_threshold) +
         "</svg>\n";
}

}  // namespace hscloc
