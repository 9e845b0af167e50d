#include "synthetic/synthetic_city_writer.h"

#include <fmt/format.h>

#include <algorithm>
#include <fstream>
#include <nlohmann/json.hpp>

#include "scene/colmap_io.h"
#include "scene/query_io.h"
#include "util/check.h"
#include "util/parallel.h"
#include "util/progress_bar.h"
#include "util/timer.h"

namespace hscloc {
namespace {

namespace fs = std::filesystem;

// Views are generated in parallel in batches and written in order, so the output does not depend
// on the thread count and at most one batch of descriptors is in memory.
constexpr size_t kViewsPerThreadPerBatch = 8;

// View keys of the random streams: database views, day queries and night queries apart.
uint64_t ViewKey(QueryCondition condition, bool is_query, size_t index) {
  const uint64_t group = is_query ? 1 + static_cast<uint64_t>(condition) : 0;
  return (group << 48) | index;
}

std::vector<SyntheticViewFeatures> MakeBatch(const SyntheticCity& city,
                                             const std::vector<SyntheticView>& views, size_t begin,
                                             size_t end, QueryCondition condition, bool is_query,
                                             int num_threads) {
  std::vector<SyntheticViewFeatures> batch(end - begin);
  ParallelFor(end - begin, num_threads, [&](size_t lo, size_t hi) {
    for (size_t i = lo; i < hi; ++i) {
      batch[i] = city.MakeViewFeatures(views[begin + i], condition,
                                       ViewKey(condition, is_query, begin + i));
    }
  });
  return batch;
}

std::ofstream OpenText(const fs::path& path) {
  std::ofstream stream(path);
  THROW_CHECK_MSG(stream.good(), "cannot write {}", path.string());
  return stream;
}

Eigen::Matrix<uint8_t, 3, 1> BlockColor(int block) {
  if (block < 0) return {128, 128, 128};
  const uint32_t hash = static_cast<uint32_t>(block) * 2654435761u;
  return {static_cast<uint8_t>(64 + (hash & 127)), static_cast<uint8_t>(64 + ((hash >> 8) & 127)),
          static_cast<uint8_t>(64 + ((hash >> 16) & 127))};
}

void WriteReadme(const fs::path& path, const SyntheticCityStats& stats) {
  std::ofstream stream = OpenText(path);
  stream
      << "# Synthetic city (hscloc synth)\n\n"
      << "A street grid of building blocks with known geometry; see stats.json for the options\n"
      << "and counts. World frame: metres, z up. Poses: cam_from_world (COLMAP).\n\n"
      << "| file | content |\n| --- | --- |\n"
      << "| map/ | COLMAP binary model of the " << stats.num_database_images
      << " database images and " << stats.num_map_points << " points |\n"
      << "| features.h5 | hloc-style local features of database and query images |\n"
      << "| queries/*_queries_with_intrinsics.txt | Aachen format query lists (day, night) |\n"
      << "| queries_gt.txt | ground-truth cam_from_world of every query |\n"
      << "| queries/point3D_ids.txt | per query keypoint, the map point it detects (-1: none) |\n";
}

}  // namespace

std::string SyntheticCityStats::ToJson() const {
  nlohmann::ordered_json json;
  json["blocks"] = num_blocks;
  json["city_points"] = num_city_points;
  json["map_points"] = num_map_points;
  json["database_images"] = num_database_images;
  json["database_keypoints"] = num_database_keypoints;
  json["database_observations"] = num_database_observations;
  json["mean_track_length"] = mean_track_length;
  json["day_queries"] = num_day_queries;
  json["night_queries"] = num_night_queries;
  return json.dump(2);
}

SyntheticCityStats WriteSyntheticCity(const SyntheticCity& city, const fs::path& output_dir,
                                      const SyntheticCityWriteOptions& options) {
  Timer timer;
  THROW_CHECK_MSG(!output_dir.empty(), "the output directory is empty");
  if (fs::exists(output_dir) && !options.overwrite) {
    ThrowInvalidArgument("{} exists already (pass overwrite to replace it)", output_dir.string());
  }
  const fs::path partial = fs::path(output_dir.string() + ".partial");
  fs::remove_all(partial);
  fs::create_directories(partial / "map");
  fs::create_directories(partial / "queries");

  const int num_threads = ResolveNumThreads(options.num_threads);
  const size_t batch_size = kViewsPerThreadPerBatch * num_threads;
  const std::vector<SyntheticView>& database_views = city.database_views();
  const std::vector<SyntheticView>& day = city.queries(QueryCondition::kDay);
  const std::vector<SyntheticView>& night = city.queries(QueryCondition::kNight);
  ProgressBar progress(
      "synth", database_views.size() + day.size() + night.size(),
      options.show_progress ? ProgressBar::Display::kAuto : ProgressBar::Display::kNever);

  H5FeatureWriter features(partial / "features.h5", options.precision);
  Reconstruction reconstruction;
  for (const Camera& camera : city.database_cameras()) {
    reconstruction.cameras.emplace(camera.camera_id, camera);
  }
  // Database observations of every city point; the map keeps those seen often enough.
  std::vector<std::vector<TrackElement>> tracks(city.points().size());
  SyntheticCityStats stats;
  for (size_t begin = 0; begin < database_views.size(); begin += batch_size) {
    const size_t end = std::min(database_views.size(), begin + batch_size);
    const std::vector<SyntheticViewFeatures> batch =
        MakeBatch(city, database_views, begin, end, QueryCondition::kDay, false, num_threads);
    for (size_t i = begin; i < end; ++i) {
      const SyntheticView& view = database_views[i];
      const SyntheticViewFeatures& made = batch[i - begin];
      features.Write(view.name, made.features, view.camera.width, view.camera.height);
      Image image;
      image.image_id = static_cast<image_t>(i + 1);
      image.name = view.name;
      image.camera_id = view.camera.camera_id;
      image.cam_from_world = view.cam_from_world;
      image.points2D.resize(made.point_of_keypoint.size());
      for (size_t k = 0; k < made.point_of_keypoint.size(); ++k) {
        image.points2D[k].xy = made.features.keypoints.row(k).transpose().cast<double>();
        const int64_t point = made.point_of_keypoint[k];
        if (point < 0) continue;
        image.points2D[k].point3D_id = static_cast<point3D_t>(point + 1);
        tracks[point].push_back({image.image_id, static_cast<point2D_t>(k)});
      }
      stats.num_database_keypoints += image.points2D.size();
      reconstruction.images.emplace(image.image_id, std::move(image));
      progress.Advance();
    }
  }

  // Decided before the tracks move into the reconstruction, for the queries' point ids too.
  std::vector<bool> point_in_map(tracks.size());
  for (size_t p = 0; p < tracks.size(); ++p) {
    point_in_map[p] = static_cast<int>(tracks[p].size()) >= city.options().min_track_length;
  }
  const auto in_map = [&](int64_t point) { return point >= 0 && point_in_map[point]; };
  for (size_t p = 0; p < tracks.size(); ++p) {
    if (!in_map(static_cast<int64_t>(p))) {
      for (const TrackElement& element : tracks[p]) {
        reconstruction.images.at(element.image_id).points2D[element.point2D_idx].point3D_id =
            kInvalidPoint3DId;
      }
      continue;
    }
    Point3D point;
    point.xyz = city.points()[p];
    point.color = BlockColor(city.point_blocks()[p]);
    double error_sum = 0;
    for (const TrackElement& element : tracks[p]) {
      const Image& image = reconstruction.images.at(element.image_id);
      const Camera& camera = reconstruction.cameras.at(image.camera_id);
      error_sum += (camera.ImgFromPointInCam(image.cam_from_world * point.xyz) -
                    image.points2D[element.point2D_idx].xy)
                       .norm();
    }
    point.error = error_sum / tracks[p].size();
    point.track = std::move(tracks[p]);
    stats.num_database_observations += point.track.size();
    reconstruction.points3D.emplace(static_cast<point3D_t>(p + 1), std::move(point));
  }
  WriteColmapModel(reconstruction, partial / "map", ColmapFormat::kBinary);

  std::ofstream ground_truth = OpenText(partial / "queries_gt.txt");
  std::ofstream point_ids = OpenText(partial / "queries" / "point3D_ids.txt");
  for (const QueryCondition condition : {QueryCondition::kDay, QueryCondition::kNight}) {
    const std::vector<SyntheticView>& queries = city.queries(condition);
    std::ofstream list =
        OpenText(partial / "queries" /
                 (QueryConditionName(condition) + "_time_queries_with_intrinsics.txt"));
    for (size_t begin = 0; begin < queries.size(); begin += batch_size) {
      const size_t end = std::min(queries.size(), begin + batch_size);
      const std::vector<SyntheticViewFeatures> batch =
          MakeBatch(city, queries, begin, end, condition, true, num_threads);
      for (size_t i = begin; i < end; ++i) {
        const SyntheticView& view = queries[i];
        const SyntheticViewFeatures& made = batch[i - begin];
        features.Write(view.name, made.features, view.camera.width, view.camera.height);
        list << FormatIntrinsicsLine(view.name, view.camera);
        ground_truth << FormatPoseLine(view.name, view.cam_from_world);
        point_ids << view.name;
        for (const int64_t point : made.point_of_keypoint) {
          point_ids << ' ' << (in_map(point) ? point + 1 : -1);
        }
        point_ids << '\n';
        progress.Advance();
      }
    }
  }
  features.Close();
  progress.Finish();

  stats.num_blocks = city.blocks().size();
  stats.num_city_points = city.points().size();
  stats.num_map_points = reconstruction.points3D.size();
  stats.num_database_images = reconstruction.images.size();
  stats.num_day_queries = day.size();
  stats.num_night_queries = night.size();
  stats.mean_track_length =
      stats.num_map_points
          ? static_cast<double>(stats.num_database_observations) / stats.num_map_points
          : 0.0;
  OpenText(partial / "stats.json") << stats.ToJson() << '\n';
  WriteReadme(partial / "README.md", stats);

  if (fs::exists(output_dir)) fs::remove_all(output_dir);
  fs::rename(partial, output_dir);
  stats.seconds = timer.ElapsedSeconds();
  return stats;
}

}  // namespace hscloc
