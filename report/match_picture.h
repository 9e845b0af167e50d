// A picture of one localized query's 2D-3D matches, to see what the pose rests on.
#pragma once

#include <filesystem>
#include <string>

#include "localization/localizer.h"
#include "scene/scene.h"

namespace hscloc {

// A self-contained SVG: the query's matched keypoints (left) and the 3D points they matched,
// projected into the winning candidate's database image (right); inliers of the pose green and
// joined by lines (every third, to keep the picture readable), rejected matches red; the photos
// under them when `images_dir` holds them by image name (an empty path: grey frames). Markers
// carry the classes `inlier` and `outlier`. Empty for a failed localization. `scene` is the one
// the result's candidates index.
std::string MatchPictureSvg(const LocalizationQuery& query, const PoseResult& result,
                            const Scene& scene, const std::filesystem::path& images_dir = {});

}  // namespace hscloc
