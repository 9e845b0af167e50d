// A top view of a map and of the queries localized in it: the map's points (subsampled when there
// are many), the database cameras, each query's ground-truth camera centre joined by a line to its
// estimated one, failures marked, with a legend and a scale bar.
//
// "Top" is along the database cameras' up direction: the opposite of their mean image y axis
// (COLMAP's y points down in the image, so for cameras held upright it points to the ground), so
// that a synthetic city (z up) and an SfM model in an arbitrary frame (Lund) both come out as
// seen from above. Camera centres are -R^T t of cam_from_world. The east axis is world x (or y,
// where x is nearly vertical) in the ground plane, north is up x east: a right-handed map, north
// up. Units are those of the world (metres).
#pragma once

#include <Eigen/Core>
#include <optional>
#include <string>
#include <vector>

#include "geometry/rigid3d.h"
#include "localization/pose_evaluation.h"
#include "scene/query_io.h"
#include "scene/scene.h"

namespace hscloc {

struct TopViewQuery {
  std::string name;
  Rigid3d true_cam_from_world;
  std::optional<Rigid3d> estimated_cam_from_world;  // none: the query was not localized
};

struct TopViewContent {
  std::vector<Eigen::Vector3d> points_in_world;
  std::vector<Rigid3d> database_cams_from_world;
  std::vector<TopViewQuery> queries;
};

// The scene's points and database cameras, and every query of `ground_truth` with its estimate
// from `estimates` (matched by image basename, as submissions name queries). Throws
// std::invalid_argument for an estimate of a query the ground truth lacks.
TopViewContent TopViewOf(const Scene& scene, const std::vector<NamedPose>& ground_truth,
                         const std::vector<NamedPose>& estimates);

struct TopViewOptions {
  std::string title = "Top view";
  // The longer side of the map's drawing area; the other follows the map's aspect.
  double map_size_px = 540;
  // Points beyond this many are subsampled evenly (every k-th).
  size_t max_points = 4000;
  // An estimate farther than this from the truth is a failure, as is a query without one.
  PoseThreshold success_threshold = {5, 10};
  // The view fits every camera and all points but this share at each end of each axis (SfM's far
  // outliers would otherwise shrink the map to a dot); points outside the view are not drawn,
  // estimates outside it are drawn on its border.
  double point_outlier_fraction = 0.01;

  // Throws std::invalid_argument naming the field.
  void Check() const;
};

// A self-contained SVG. Its markers carry classes: `point`, `database-camera`, `query-truth`,
// `query-estimate`, `query-error` (the line from truth to estimate) and `query-failure` (a cross
// on the truth of a failed query); each query's markers carry its name and errors as a tooltip.
std::string TopViewSvg(const TopViewContent& content, const TopViewOptions& options = {});

}  // namespace hscloc
