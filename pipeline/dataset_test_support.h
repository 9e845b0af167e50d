// Miniature datasets for the pipeline's tests: empty photo files, a model without points.
#pragma once

#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "scene/colmap_io.h"

namespace hscloc::testing {

inline void Touch(const std::filesystem::path& path, const std::string& text = "") {
  std::filesystem::create_directories(path.parent_path());
  std::ofstream(path) << text;
}

// A COLMAP text model of one camera and the images named, without points.
inline void WriteModel(const std::filesystem::path& dir, const std::vector<std::string>& names) {
  Reconstruction model;
  model.cameras[1] = Camera::FromModelName(1, "PINHOLE", 640, 480, {500, 500, 320, 240});
  image_t id = 1;
  for (const std::string& name : names) {
    Image image;
    image.image_id = id;
    image.name = name;
    image.camera_id = 1;
    model.images[id++] = image;
  }
  WriteColmapModel(model, dir, ColmapFormat::kText);
}

inline std::string QueryLine(const std::string& name) {
  return name + " PINHOLE 640 480 500 500 320 240\n";
}

// The layout of data/: two map photos and a query with its ground truth.
inline void MakeHsclocDataset(const std::filesystem::path& dir) {
  for (const char* name : {"a.jpg", "b.jpg", "q.jpg"}) Touch(dir / "images" / name);
  WriteModel(dir / "map", {"a.jpg", "b.jpg"});
  Touch(dir / "queries_with_intrinsics.txt", QueryLine("q.jpg"));
  Touch(dir / "queries_gt.txt", "q.jpg 1 0 0 0 0 0 0\n");
}

}  // namespace hscloc::testing
