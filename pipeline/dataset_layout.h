// Where a localization dataset keeps its photos, its map model and its queries. Two layouts are
// understood:
//   hscloc    DIR/images/, DIR/map/ (COLMAP model of the map images),
//             DIR/queries_with_intrinsics.txt, optionally DIR/queries_gt.txt (the real sets under
//             data/);
//   aachen    DIR/images/images_upright/, DIR/3D-models/<model>/ (one COLMAP model),
//             DIR/queries/*_queries_with_intrinsics.txt (Aachen Day-Night v1.1, as downloaded).
#pragma once

#include <filesystem>
#include <optional>
#include <string>
#include <utility>
#include <vector>

namespace hscloc {

struct DatasetLayout {
  std::string kind;  // "hscloc" or "aachen"
  std::filesystem::path images_dir;
  std::filesystem::path model_dir;
  // Condition name (the list's name before "_queries_with_intrinsics.txt"; "all" for the hscloc
  // layout) and list, sorted by name.
  std::vector<std::pair<std::string, std::filesystem::path>> query_lists;
  std::optional<std::filesystem::path> ground_truth;
};

// The layout of `dir`. Throws std::invalid_argument naming, for each layout, the first file or
// folder it lacks, when `dir` is in neither.
DatasetLayout FindDatasetLayout(const std::filesystem::path& dir);

// The photos the dataset needs, map images first, then the queries, as names relative to
// layout.images_dir. Throws std::invalid_argument naming the photos that are missing (a model
// whose images are not the folder's photos, a query list naming a missing photo) or a query listed
// twice.
std::vector<std::string> DatasetPhotos(const DatasetLayout& layout);

}  // namespace hscloc
