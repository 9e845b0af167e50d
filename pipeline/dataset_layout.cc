#include "pipeline/dataset_layout.h"

#include <fmt/format.h>

#include <algorithm>
#include <set>

#include "scene/colmap_io.h"
#include "scene/query_io.h"
#include "util/check.h"

namespace hscloc {
namespace {

namespace fs = std::filesystem;

constexpr const char* kQueryListSuffix = "_queries_with_intrinsics.txt";

bool HoldsColmapModel(const fs::path& dir) {
  return fs::is_regular_file(dir / "cameras.bin") || fs::is_regular_file(dir / "cameras.txt");
}

// The first of the layout's required paths that `dir` lacks, empty when none.
std::string FirstMissingOfHscloc(const fs::path& dir) {
  for (const char* required : {"images", "map", "queries_with_intrinsics.txt"}) {
    if (!fs::exists(dir / required)) return required;
  }
  if (!HoldsColmapModel(dir / "map")) return "map/cameras.bin";
  return "";
}

std::optional<fs::path> AachenModelDir(const fs::path& dir) {
  std::vector<fs::path> models;
  if (fs::is_directory(dir / "3D-models")) {
    for (const fs::directory_entry& entry : fs::directory_iterator(dir / "3D-models")) {
      if (entry.is_directory() && HoldsColmapModel(entry.path())) models.push_back(entry.path());
    }
  }
  if (models.size() > 1) {
    ThrowInvalidArgument("{} holds {} COLMAP models ({}, {}, ...); keep only the map's",
                         (dir / "3D-models").string(), models.size(), models[0].filename().string(),
                         models[1].filename().string());
  }
  if (models.empty()) return std::nullopt;
  return models.front();
}

std::vector<std::pair<std::string, fs::path>> AachenQueryLists(const fs::path& dir) {
  std::vector<std::pair<std::string, fs::path>> lists;
  if (!fs::is_directory(dir / "queries")) return lists;
  const std::string suffix = kQueryListSuffix;
  for (const fs::directory_entry& entry : fs::directory_iterator(dir / "queries")) {
    const std::string name = entry.path().filename().string();
    if (entry.is_regular_file() && name.size() > suffix.size() &&
        name.compare(name.size() - suffix.size(), suffix.size(), suffix) == 0) {
      lists.emplace_back(name.substr(0, name.size() - suffix.size()), entry.path());
    }
  }
  std::sort(lists.begin(), lists.end());
  return lists;
}

std::string FirstMissingOfAachen(const fs::path& dir, const std::optional<fs::path>& model,
                                 bool has_query_lists) {
  if (!fs::is_directory(dir / "images" / "images_upright")) return "images/images_upright";
  if (!model) return "3D-models/<model>/cameras.bin";
  if (!has_query_lists) return std::string("queries/*") + kQueryListSuffix;
  return "";
}

// "a, b, c and 4 more"
std::string FirstNames(const std::vector<std::string>& names) {
  std::string text;
  for (size_t i = 0; i < std::min<size_t>(3, names.size()); ++i) {
    text += (i > 0 ? ", " : "") + names[i];
  }
  if (names.size() > 3) text += fmt::format(" and {} more", names.size() - 3);
  return text;
}

}  // namespace

DatasetLayout FindDatasetLayout(const fs::path& dir) {
  if (!fs::is_directory(dir))
    ThrowInvalidArgument("dataset folder {} does not exist", dir.string());
  const std::string hscloc_missing = FirstMissingOfHscloc(dir);
  if (hscloc_missing.empty()) {
    DatasetLayout layout{
        "hscloc", dir / "images", dir / "map", {{"all", dir / "queries_with_intrinsics.txt"}}, {}};
    if (fs::is_regular_file(dir / "queries_gt.txt")) layout.ground_truth = dir / "queries_gt.txt";
    return layout;
  }
  const std::optional<fs::path> model = AachenModelDir(dir);
  std::vector<std::pair<std::string, fs::path>> lists = AachenQueryLists(dir);
  const std::string aachen_missing = FirstMissingOfAachen(dir, model, !lists.empty());
  if (aachen_missing.empty()) {
    return {"aachen", dir / "images" / "images_upright", *model, std::move(lists), {}};
  }
  ThrowInvalidArgument(
      "{} is not a dataset: it lacks {} (the layout of data/: images/, map/, "
      "queries_with_intrinsics.txt) and {} (the layout of Aachen Day-Night v1.1: "
      "images/images_upright/, 3D-models/<model>/, queries/*_queries_with_intrinsics.txt)",
      dir.string(), (dir / hscloc_missing).string(), (dir / aachen_missing).string());
}

std::vector<std::string> DatasetPhotos(const DatasetLayout& layout) {
  std::vector<std::string> photos;
  for (const auto& [id, image] : ReadColmapModel(layout.model_dir).images) {
    photos.push_back(image.name);
  }
  std::sort(photos.begin(), photos.end());
  std::set<std::string> seen(photos.begin(), photos.end());
  std::vector<std::string> missing;
  for (const std::string& name : photos) {
    if (!fs::is_regular_file(layout.images_dir / name)) missing.push_back(name);
  }
  if (!missing.empty()) {
    ThrowInvalidArgument(
        "the model {} does not match the photos: {} of its {} images are not under {} ({})",
        layout.model_dir.string(), missing.size(), photos.size(), layout.images_dir.string(),
        FirstNames(missing));
  }
  for (const auto& [condition, list] : layout.query_lists) {
    for (const QueryWithIntrinsics& query : ReadQueryList(list)) {
      if (!seen.insert(query.name).second) {
        ThrowInvalidArgument("{} lists {}, which is a map image or a query listed before",
                             list.string(), query.name);
      }
      if (!fs::is_regular_file(layout.images_dir / query.name)) missing.push_back(query.name);
      photos.push_back(query.name);
    }
    if (!missing.empty()) {
      ThrowInvalidArgument("{} names {} photo(s) that are not under {}: {}", list.string(),
                           missing.size(), layout.images_dir.string(), FirstNames(missing));
    }
  }
  return photos;
}

}  // namespace hscloc
