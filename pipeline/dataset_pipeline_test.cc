#include "pipeline/dataset_pipeline.h"

#include <fmt/format.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <atomic>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>

#include "features/image_extraction.h"
#include "map/map_bundle.h"
#include "pipeline/dataset_test_support.h"
#include "scene/colmap_io.h"
#include "scene/feature_io.h"
#include "scene/query_io.h"
#include "util/testing.h"

namespace hscloc {
namespace {

namespace fs = std::filesystem;
using ::testing::HasSubstr;

PipelineOptions NearestNeighborOptions(const std::string& colmap) {
  PipelineOptions options;
  options.matcher = Matcher::kNearestNeighbor;
  options.colmap_executable = colmap;
  options.show_progress = false;
  return options;
}

std::vector<bool> SkippedSteps(const PipelineSummary& summary) {
  std::vector<bool> skipped;
  for (const PipelineStepReport& step : summary.steps) skipped.push_back(step.skipped);
  return skipped;
}

std::string ReadText(const fs::path& path) {
  std::ifstream file(path);
  std::stringstream text;
  text << file.rdbuf();
  return text.str();
}

// A folder in neither layout, a query list naming a missing photo, a model whose images are not
// the photos: each refused before the output folder is made.
TEST(DatasetPipelineTest, BadInputWritesNothing) {
  testing::TempDir dir;
  std::ostringstream log;
  const PipelineOptions options = NearestNeighborOptions("colmap");
  const auto refusal = [&](const fs::path& dataset) {
    return testing::InvalidArgumentMessage(
        [&] { RunDatasetPipeline(dataset, dir / "out", options, log); });
  };
  fs::create_directories(dir / "not-a-dataset" / "images");
  EXPECT_THAT(refusal(dir / "not-a-dataset"), HasSubstr("is not a dataset"));

  testing::MakeHsclocDataset(dir / "lost-query");
  testing::Touch(dir / "lost-query" / "queries_with_intrinsics.txt",
                 testing::QueryLine("q.jpg") + testing::QueryLine("lost.jpg"));
  EXPECT_THAT(refusal(dir / "lost-query"), HasSubstr("lost.jpg"));

  testing::MakeHsclocDataset(dir / "other-model");
  testing::WriteModel(dir / "other-model" / "map", {"a.jpg", "elsewhere.jpg"});
  EXPECT_THAT(refusal(dir / "other-model"), HasSubstr("does not match the photos"));
  EXPECT_FALSE(fs::exists(dir / "out"));
}

TEST(DatasetPipelineTest, RefusesAnOutputFolderOfAnotherToolOrFeature) {
  HSCLOC_REQUIRE_REAL_DATA(lund, "lund");
  testing::TempDir dir;
  std::ostringstream log;
  PipelineOptions options = NearestNeighborOptions("colmap");
  fs::create_directories(dir / "busy");
  std::ofstream(dir / "busy" / "notes.txt") << "mine\n";
  EXPECT_THAT(testing::InvalidArgumentMessage(
                  [&] { RunDatasetPipeline(lund, dir / "busy", options, log); }),
              HasSubstr("not empty"));

  // A record of SIFT features: the XFeat run must not reuse that folder.
  fs::create_directories(dir / "sift");
  std::ofstream(dir / "sift" / "pipeline.json")
      << "{\"dataset\": \"" << fs::weakly_canonical(lund).string() << "\", \"feature\": \"sift\"}";
  options.feature = FeatureType::kXFeat;
  EXPECT_THAT(testing::InvalidArgumentMessage(
                  [&] { RunDatasetPipeline(lund, dir / "sift", options, log); }),
              HasSubstr("with sift features"));
  EXPECT_FALSE(fs::exists(dir / "sift" / "features.partial.h5"));
}

// Lund with XFeat and the nearest-neighbour matcher: a run that stopped during the extraction
// resumes after the photos it had written, a finished run does nothing, and a removed map is
// rebuilt with the submission while the features and the model are kept; then the network, after
// a stop.
TEST(DatasetPipelineTest, LundResumesAnInterruptedRunAndSkipsAFinishedOne) {
  HSCLOC_REQUIRE_REAL_DATA(lund, "lund");
  HSCLOC_REQUIRE_COLMAP(colmap);
  testing::TempDir dir;
  const fs::path out = dir / "out";
  const PipelineOptions options = NearestNeighborOptions(colmap);
  std::ostringstream log;
  // What a run stopped after its first chunk of photos leaves.
  fs::create_directories(out);
  std::ofstream(out / "pipeline.json") << nlohmann::json{
      {"dataset", fs::weakly_canonical(lund).string()},
      {"feature", "xfeat"}}.dump();
  const std::vector<std::string> photos = DatasetPhotos(FindDatasetLayout(lund));
  ImageExtractionOptions extraction;
  extraction.extractor.type = FeatureType::kXFeat;
  extraction.show_progress = false;
  ExtractImagesToH5(lund / "images", {photos.begin(), photos.begin() + 3},
                    out / "features.partial.h5", extraction);

  const PipelineSummary first = RunDatasetPipeline(lund, out, options, log);
  EXPECT_EQ(SkippedSteps(first), (std::vector<bool>{false, false, false, false}));
  EXPECT_THAT(first.steps[0].detail,
              HasSubstr(fmt::format("{} extracted by this run", photos.size() - 3)));
  EXPECT_EQ(OpenFeatureReader(out / "features.h5")->ImageNames().size(), photos.size());
  EXPECT_FALSE(fs::exists(out / "features.partial.h5"));
  EXPECT_EQ(first.submission, out / "submission-nn.txt");
  const std::vector<NamedPose> poses = ReadPoses(first.submission);
  EXPECT_EQ(poses.size(), ReadQueryList(lund / "queries_with_intrinsics.txt").size());
  // Every Lund query within (0.5 m, 5 deg) with nearest-neighbour matching on the XFeat map.
  ASSERT_FALSE(first.errors.empty());
  for (const QueryPoseError& error : first.errors) {
    EXPECT_TRUE(error.estimated) << error.name;
    EXPECT_LT(error.position, 0.5) << error.name;
    EXPECT_LT(error.rotation_deg, 5.0) << error.name;
  }
  const std::string submission = ReadText(first.submission);

  const auto map_written = fs::last_write_time(out / "map" / "manifest.json");
  const PipelineSummary second = RunDatasetPipeline(lund, out, options, log);
  EXPECT_TRUE(second.NothingToDo());
  EXPECT_EQ(fs::last_write_time(out / "map" / "manifest.json"), map_written);
  EXPECT_EQ(ReadText(second.submission), submission);

  fs::remove_all(out / "map");
  const PipelineSummary third = RunDatasetPipeline(lund, out, options, log);
  EXPECT_EQ(SkippedSteps(third), (std::vector<bool>{true, true, false, false}));
  EXPECT_EQ(ReadText(third.submission), submission);
  EXPECT_THAT(log.str(), HasSubstr("[1/4] features: complete, skipped"));

  // The network on the same map, stopped (as by Ctrl-C) as its step begins: nothing is published
  // and the nearest-neighbour submission, whose map is unchanged, stays; the next run trains.
  std::atomic<bool> stop{true};
  PipelineOptions network_options = options;
  network_options.matcher = Matcher::kNetwork;
  network_options.max_iterations = 4;
  network_options.stop_requested = &stop;
  const PipelineSummary stopped = RunDatasetPipeline(lund, out, network_options, log);
  EXPECT_TRUE(stopped.Interrupted());
  ASSERT_EQ(stopped.steps.size(), 4u);  // the submission step did not start
  EXPECT_TRUE(stopped.steps[3].interrupted);
  EXPECT_FALSE(MapBundle::Open(out / "map", std::vector<std::string>{}).HasBlob("network.pt"));
  EXPECT_FALSE(fs::exists(out / "submission.txt"));
  EXPECT_TRUE(fs::exists(out / "submission-nn.txt"));
  stop = false;
  const PipelineSummary resumed = RunDatasetPipeline(lund, out, network_options, log);
  EXPECT_EQ(SkippedSteps(resumed), (std::vector<bool>{true, true, true, false, false}));
  EXPECT_THAT(resumed.steps[3].detail, HasSubstr("4 iterations"));
  EXPECT_FALSE(fs::exists(out / "map.checkpoint.pt"));
  EXPECT_EQ(ReadPoses(out / "submission.txt").size(), poses.size());
}

// The KITTI street (140 map frames, 20 queries along 115 m) from its photos with XFeat: the
// nearest-neighbour baseline on the pipeline's map places every query within a few centimetres of
// the pseudo ground truth (COLMAP's own registration: within 7 mm; see the set's README).
TEST(DatasetPipelineTest, Kitti07StreetEveryQueryWithNearestNeighbours) {
  HSCLOC_REQUIRE_REAL_DATA(kitti, "kitti-07");
  HSCLOC_REQUIRE_COLMAP(colmap);
  testing::TempDir dir;
  std::ostringstream log;
  const PipelineSummary summary =
      RunDatasetPipeline(kitti, dir / "out", NearestNeighborOptions(colmap), log);
  ASSERT_EQ(summary.errors.size(), 20u);
  for (const QueryPoseError& error : summary.errors) {
    EXPECT_TRUE(error.estimated) << error.name;
    EXPECT_LT(error.position, 0.05) << error.name;
    EXPECT_LT(error.rotation_deg, 0.5) << error.name;
  }
}

// Lund rearranged as Aachen Day-Night v1.1 is laid out (photos under images/images_upright/db
// and query/day/milestone, the model under 3D-models/, the day list under queries/): the
// submission names the queries by their basenames, as visuallocalization.net expects, and places
// them as the layout of data/ does.
TEST(DatasetPipelineTest, TheLayoutOfAachenEndToEnd) {
  HSCLOC_REQUIRE_REAL_DATA(lund, "lund");
  HSCLOC_REQUIRE_COLMAP(colmap);
  testing::TempDir dir;
  const fs::path aachen = dir / "aachen";
  const fs::path upright = aachen / "images" / "images_upright";
  Reconstruction model = ReadColmapModel(lund / "map");
  fs::create_directories(upright / "db");
  for (auto& [id, image] : model.images) {
    fs::copy_file(lund / "images" / image.name, upright / "db" / image.name);
    image.name = "db/" + image.name;
  }
  WriteColmapModel(model, aachen / "3D-models" / "aachen_v_1_1", ColmapFormat::kBinary);
  fs::create_directories(upright / "query" / "day" / "milestone");
  fs::create_directories(aachen / "queries");
  std::ofstream list(aachen / "queries" / "day_time_queries_with_intrinsics.txt");
  for (const QueryWithIntrinsics& query : ReadQueryList(lund / "queries_with_intrinsics.txt")) {
    fs::copy_file(lund / "images" / query.name,
                  upright / "query" / "day" / "milestone" / query.name);
    list << FormatIntrinsicsLine("query/day/milestone/" + query.name, query.camera);
  }
  list.close();

  std::ostringstream log;
  const PipelineSummary summary =
      RunDatasetPipeline(aachen, dir / "out", NearestNeighborOptions(colmap), log);
  EXPECT_THAT(log.str(), HasSubstr("(aachen layout)"));
  EXPECT_TRUE(summary.errors.empty());  // Aachen's ground truth stays with its server
  const std::vector<QueryPoseError> errors =
      ComputePoseErrors(ReadPoses(lund / "queries_gt.txt"), ReadPoses(summary.submission));
  ASSERT_EQ(errors.size(), 5u);
  for (const QueryPoseError& error : errors) {
    EXPECT_TRUE(error.estimated) << error.name;
    EXPECT_LT(error.position, 0.5) << error.name;
    EXPECT_LT(error.rotation_deg, 5.0) << error.name;
  }
}

TEST(DatasetPipelineTest, AnUnreadablePartialFeatureFileIsExtractedAgain) {
  HSCLOC_REQUIRE_REAL_DATA(lund, "lund");
  testing::TempDir dir;
  // Three Lund photos, a model of two of them, the third as a query; the run stops after the
  // features, at a COLMAP that does not exist.
  const fs::path dataset = dir / "dataset";
  fs::create_directories(dataset / "images");
  for (const char* name : {"01.jpg", "02.jpg", "05.jpg"}) {
    fs::copy_file(lund / "images" / name, dataset / "images" / name);
  }
  Reconstruction model = ReadColmapModel(lund / "map");
  for (auto it = model.images.begin(); it != model.images.end();) {
    const bool kept = it->second.name == "01.jpg" || it->second.name == "02.jpg";
    it = kept ? std::next(it) : model.images.erase(it);
  }
  model.points3D.clear();
  for (auto& [id, image] : model.images) image.points2D.clear();
  WriteColmapModel(model, dataset / "map", ColmapFormat::kText);
  std::ofstream(dataset / "queries_with_intrinsics.txt")
      << "05.jpg SIMPLE_RADIAL 1024 768 995 512 384 0\n";

  const fs::path out = dir / "out";
  fs::create_directories(out);
  std::ofstream(out / "pipeline.json") << nlohmann::json{
      {"dataset", fs::weakly_canonical(dataset).string()},
      {"feature", "xfeat"}}.dump();
  std::ofstream(out / "features.partial.h5") << "not an HDF5 file";
  const PipelineOptions options = NearestNeighborOptions((dir / "no-colmap").string());
  std::ostringstream log;
  EXPECT_ANY_THROW(RunDatasetPipeline(dataset, out, options, log));
  EXPECT_THAT(log.str(), HasSubstr("cannot be read"));
  EXPECT_EQ(OpenFeatureReader(out / "features.h5")->ImageNames().size(), 3u);
  EXPECT_FALSE(fs::exists(out / "model"));
}

}  // namespace
}  // namespace hscloc
