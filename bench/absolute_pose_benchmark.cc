// EstimateAbsolutePose on Aachen-like queries: 2000 keypoint-to-point matches in a 1600 x 1200
// SIMPLE_RADIAL image, points 5 to 80 m away, 1 px keypoint noise, and wrong matches that pair a
// keypoint with the point of another pixel. Arguments: solver (0 LO-RANSAC, 1 OpenCV USAC),
// inlier percentage, and stop_sampling_past_inliers (USAC cannot stop early and ignores it).
// Besides time, the counters report the accuracy against the true pose.
#include <benchmark/benchmark.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <utility>
#include <vector>

#include "pose/absolute_pose.h"
#include "util/random.h"

namespace hscloc {
namespace {

constexpr int kNumCorrespondences = 2000;
constexpr int kNumQueries = 64;
constexpr double kNoisePx = 1.0;

struct Query {
  Camera camera;
  Rigid3d cam_from_world;
  std::vector<Eigen::Vector2d> keypoints_px;
  std::vector<Eigen::Vector3d> points_in_world;
};

Query MakeQuery(double inlier_ratio, uint64_t seed) {
  Random random(seed);
  Query query;
  query.camera =
      Camera::FromModelName(1, "SIMPLE_RADIAL", 1600, 1200,
                            {random.Uniform(1200, 2000), 800 + random.Uniform(-10, 10),
                             600 + random.Uniform(-10, 10), random.Uniform(-0.05, 0.05)});
  query.cam_from_world =
      Rigid3d(Eigen::Quaterniond(random.Normal(), random.Normal(), random.Normal(), random.Normal())
                  .normalized(),
              Eigen::Vector3d(random.Normal(0, 100), random.Normal(0, 100), random.Normal(0, 10)));
  const Rigid3d world_from_cam = query.cam_from_world.Inverse();
  const auto random_pixel = [&] {
    return Eigen::Vector2d(random.Uniform(0, 1600), random.Uniform(0, 1200));
  };
  const int num_inliers = static_cast<int>(inlier_ratio * kNumCorrespondences);
  for (int i = 0; i < kNumCorrespondences; ++i) {
    const Eigen::Vector2d pixel = random_pixel();
    const Eigen::Vector3d ray = query.camera.CamFromImg(pixel).homogeneous();
    query.points_in_world.push_back(world_from_cam * (random.Uniform(5, 80) * ray));
    query.keypoints_px.push_back(
        i < num_inliers ? pixel + kNoisePx * Eigen::Vector2d(random.Normal(), random.Normal())
                        : random_pixel());
  }
  for (int i = kNumCorrespondences - 1; i > 0; --i) {
    const int j = static_cast<int>(random.UniformInt(i + 1));
    std::swap(query.keypoints_px[i], query.keypoints_px[j]);
    std::swap(query.points_in_world[i], query.points_in_world[j]);
  }
  return query;
}

double Median(std::vector<double> values) {
  if (values.empty()) return 0.0;
  std::nth_element(values.begin(), values.begin() + values.size() / 2, values.end());
  return values[values.size() / 2];
}

void BM_EstimateAbsolutePose(benchmark::State& state) {
  const auto solver = static_cast<AbsolutePoseOptions::Solver>(state.range(0));
  const double inlier_ratio = state.range(1) / 100.0;
  const int stop_sampling_past_inliers = static_cast<int>(state.range(2));
  std::vector<Query> queries;
  for (int i = 0; i < kNumQueries; ++i) queries.push_back(MakeQuery(inlier_ratio, 1000 + i));
  AbsolutePoseOptions options;
  options.solver = solver;
  options.stop_sampling_past_inliers = stop_sampling_past_inliers;

  std::vector<double> rotation_errors_deg, position_errors_cm;
  double iterations = 0, inliers = 0, successes = 0;
  uint64_t call = 0;
  for (auto _ : state) {
    const Query& query = queries[call % kNumQueries];
    options.seed = call++;
    const AbsolutePoseResult result =
        EstimateAbsolutePose(query.camera, query.keypoints_px, query.points_in_world, options);
    benchmark::DoNotOptimize(result.cam_from_world);
    iterations += result.num_iterations;
    inliers += result.num_inliers;
    successes += result.success;
    rotation_errors_deg.push_back(RotationErrorDeg(result.cam_from_world, query.cam_from_world));
    position_errors_cm.push_back(100 * PositionError(result.cam_from_world, query.cam_from_world));
  }
  const double calls = static_cast<double>(call);
  state.counters["iterations"] = iterations / calls;
  state.counters["inliers"] = inliers / calls;
  state.counters["success"] = successes / calls;
  state.counters["wrong_pose"] = std::count_if(position_errors_cm.begin(), position_errors_cm.end(),
                                               [](double error_cm) { return error_cm > 20.0; }) /
                                 calls;
  state.counters["rot_med_deg"] = Median(rotation_errors_deg);
  state.counters["rot_max_deg"] =
      *std::max_element(rotation_errors_deg.begin(), rotation_errors_deg.end());
  state.counters["pos_med_cm"] = Median(position_errors_cm);
  state.counters["pos_max_cm"] =
      *std::max_element(position_errors_cm.begin(), position_errors_cm.end());
}

void SolverArguments(benchmark::internal::Benchmark* benchmark) {
  for (const int inlier_pct : {50, 20, 10}) {
    benchmark->Args({0, inlier_pct, 100});
    benchmark->Args({0, inlier_pct, 0});
    benchmark->Args({1, inlier_pct, 100});
  }
}

BENCHMARK(BM_EstimateAbsolutePose)
    ->ArgNames({"solver", "inlier_pct", "early_stop"})
    ->Apply(SolverArguments)
    ->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace hscloc
