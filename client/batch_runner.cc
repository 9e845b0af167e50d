#include "client/batch_runner.h"

#include <fmt/format.h>

#include <algorithm>
#include <atomic>
#include <exception>
#include <fstream>
#include <mutex>
#include <thread>

#include "util/check.h"
#include "util/progress_bar.h"
#include "util/timer.h"

namespace hscloc {

wire::Camera CameraToWire(const Camera& camera) {
  std::string text =
      fmt::format("{} {} {}", CameraModelName(camera.model_id), camera.width, camera.height);
  for (const double param : camera.params) text += fmt::format(" {}", param);
  return ParseCamera(text);
}

wire::LocalizeRequest RequestFromFeatures(const std::string& name, const wire::Camera& camera,
                                          const ImageFeatures& features, bool float16) {
  const std::vector<float> keypoints(features.keypoints.data(),
                                     features.keypoints.data() + features.keypoints.size());
  const std::vector<float> descriptors(features.descriptors.data(),
                                       features.descriptors.data() + features.descriptors.size());
  return MakeLocalizeRequest(name, camera, keypoints, descriptors,
                             static_cast<uint32_t>(features.Dimension()), float16);
}

Rigid3d PoseFromWire(const wire::Pose& pose) {
  return Rigid3d(Eigen::Quaterniond(pose.qw(), pose.qx(), pose.qy(), pose.qz()),
                 Eigen::Vector3d(pose.tx(), pose.ty(), pose.tz()));
}

void BatchOptions::Check() const {
  if (out.empty()) ThrowInvalidArgument("BatchOptions.out is empty");
  if (inflight < 1) ThrowInvalidArgument("BatchOptions.inflight is {}, must be >= 1", inflight);
}

BatchSummary RunBatch(const std::vector<QueryWithIntrinsics>& queries,
                      const FeatureReader& features, const BatchOptions& options) {
  options.Check();
  for (const QueryWithIntrinsics& query : queries) {
    if (!features.HasImage(query.name)) {
      ThrowInvalidArgument("{}: no features for query '{}'", features.path().string(), query.name);
    }
  }
  BatchSummary summary;
  summary.num_queries = queries.size();
  summary.failures_path = options.out.string() + ".failures.txt";
  if (!options.out.parent_path().empty()) {
    std::filesystem::create_directories(options.out.parent_path());
  }
  std::ofstream submission(options.out);
  std::ofstream failures(summary.failures_path);
  if (!submission || !failures) ThrowInvalidArgument("cannot write {}", options.out.string());
  ProgressBar progress(
      "batch", queries.size(),
      options.show_progress ? ProgressBar::Display::kAuto : ProgressBar::Display::kNever);
  std::mutex mutex;
  std::atomic<size_t> next{0};
  std::exception_ptr error;
  // Answers come in any order; each query's lines are held until those before it are written,
  // so that the files are in query order, the same from run to run, and grow as the batch goes.
  struct Answer {
    bool done = false;
    std::string pose_line;     // empty: refused
    std::string failure_line;  // empty: localized
  };
  std::vector<Answer> answers(queries.size());
  size_t written = 0;
  const auto write_ready = [&] {
    for (; written < answers.size() && answers[written].done; ++written) {
      submission << answers[written].pose_line;
      failures << answers[written].failure_line;
    }
    submission << std::flush;
    failures << std::flush;
  };
  const Timer timer;
  const auto worker = [&] {
    try {
      LocalizationClient client(options.client);
      for (size_t i = next++; i < queries.size(); i = next++) {
        const QueryWithIntrinsics& query = queries[i];
        const wire::LocalizeResponse response = client.Localize(RequestFromFeatures(
            query.name, CameraToWire(query.camera), features.Read(query.name), options.float16));
        std::lock_guard<std::mutex> lock(mutex);
        const std::string basename = ImageBasename(query.name);
        Answer& answer = answers[i];
        if (response.status() == wire::OK || response.status() == wire::NOT_LOCALIZED) {
          // As `hscloc localize`: a failed query gets the top-1 retrieved image's pose.
          answer.pose_line = FormatPoseLine(basename, PoseFromWire(response.cam_from_world()));
        }
        if (response.status() == wire::OK) {
          ++summary.num_localized;
        } else {
          ++summary.num_failed;
          answer.failure_line =
              fmt::format("{} {} {}\n", basename, wire::Status_Name(response.status()),
                          response.error_message());
        }
        answer.done = true;
        write_ready();
        progress.SetStatus(
            fmt::format("{} localized, {} failed", summary.num_localized, summary.num_failed));
        progress.Advance();
      }
    } catch (...) {
      std::lock_guard<std::mutex> lock(mutex);
      if (!error) error = std::current_exception();
      next = queries.size();
    }
  };
  std::vector<std::thread> threads;
  for (int t = 0; t < options.inflight; ++t) threads.emplace_back(worker);
  for (std::thread& thread : threads) thread.join();
  progress.Finish();
  if (error) std::rethrow_exception(error);
  summary.seconds = timer.ElapsedSeconds();
  return summary;
}

}  // namespace hscloc
