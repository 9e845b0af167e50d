#include "scene/reconstruction.h"

#include <algorithm>
#include <string>
#include <tuple>
#include <vector>

#include "util/check.h"

namespace hscloc {

void Reconstruction::Check() const {
  for (const auto& [camera_id, camera] : cameras) {
    if (camera.camera_id != camera_id) {
      ThrowInvalidArgument("camera {} is stored under id {}", camera.camera_id, camera_id);
    }
    camera.Check();
  }

  size_t num_points2D_with_point3D = 0;
  for (const auto& [image_id, image] : images) {
    if (image.image_id != image_id) {
      ThrowInvalidArgument("image {} is stored under id {}", image.image_id, image_id);
    }
    if (cameras.count(image.camera_id) == 0) {
      ThrowInvalidArgument("image {} (name '{}'): camera {} does not exist", image_id, image.name,
                           image.camera_id);
    }
    for (const Point2D& point2D : image.points2D) {
      num_points2D_with_point3D += point2D.HasPoint3D();
    }
  }

  std::vector<TrackElement> sorted_track;
  size_t num_track_elements = 0;
  for (const auto& [point3D_id, point3D] : points3D) {
    for (const TrackElement& element : point3D.track) {
      const auto image = images.find(element.image_id);
      if (image == images.end()) {
        ThrowInvalidArgument("point3D {}: track names image {}, which does not exist", point3D_id,
                             element.image_id);
      }
      const std::vector<Point2D>& points2D = image->second.points2D;
      if (element.point2D_idx >= points2D.size()) {
        ThrowInvalidArgument("point3D {}: track names 2D point {} of image {}, which has {}",
                             point3D_id, element.point2D_idx, element.image_id, points2D.size());
      }
      if (points2D[element.point2D_idx].point3D_id != point3D_id) {
        ThrowInvalidArgument(
            "point3D {}: track names 2D point {} of image {}, whose point3D_id is {}", point3D_id,
            element.point2D_idx, element.image_id,
            points2D[element.point2D_idx].HasPoint3D()
                ? std::to_string(points2D[element.point2D_idx].point3D_id)
                : std::string("none"));
      }
    }
    sorted_track = point3D.track;
    const auto by_image_and_idx = [](const TrackElement& a, const TrackElement& b) {
      return std::tie(a.image_id, a.point2D_idx) < std::tie(b.image_id, b.point2D_idx);
    };
    std::sort(sorted_track.begin(), sorted_track.end(), by_image_and_idx);
    const auto duplicate = std::adjacent_find(
        sorted_track.begin(), sorted_track.end(), [](const TrackElement& a, const TrackElement& b) {
          return a.image_id == b.image_id && a.point2D_idx == b.point2D_idx;
        });
    if (duplicate != sorted_track.end()) {
      ThrowInvalidArgument("point3D {}: track names 2D point {} of image {} twice", point3D_id,
                           duplicate->point2D_idx, duplicate->image_id);
    }
    num_track_elements += point3D.track.size();
  }

  // Each track element was matched to a distinct 2D point carrying its point's id, so equal
  // counts mean every such 2D point is in its point's track, and the lookups per 2D point below
  // are needed only to name the one that is not.
  if (num_track_elements == num_points2D_with_point3D) return;
  for (const auto& [image_id, image] : images) {
    for (size_t idx = 0; idx < image.points2D.size(); ++idx) {
      const Point2D& point2D = image.points2D[idx];
      if (!point2D.HasPoint3D()) continue;
      const auto point3D = points3D.find(point2D.point3D_id);
      if (point3D == points3D.end()) {
        ThrowInvalidArgument(
            "image {} (name '{}'): 2D point {} names point3D {}, which does not exist", image_id,
            image.name, idx, point2D.point3D_id);
      }
      const std::vector<TrackElement>& track = point3D->second.track;
      const bool in_track = std::any_of(track.begin(), track.end(), [&](const TrackElement& e) {
        return e.image_id == image_id && e.point2D_idx == idx;
      });
      if (!in_track) {
        ThrowInvalidArgument(
            "image {} (name '{}'): 2D point {} names point3D {}, whose track "
            "does not contain it",
            image_id, image.name, idx, point2D.point3D_id);
      }
    }
  }
}

size_t Reconstruction::NumObservations() const {
  size_t num_observations = 0;
  for (const auto& [point3D_id, point3D] : points3D) num_observations += point3D.track.size();
  return num_observations;
}

}  // namespace hscloc
