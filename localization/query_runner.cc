#include "localization/query_runner.h"

#include <fmt/format.h>

#include <algorithm>
#include <atomic>
#include <exception>
#include <fstream>
#include <iterator>
#include <mutex>
#include <thread>
#include <unordered_set>

#include "model/network.h"
#include "util/check.h"
#include "util/parallel.h"
#include "util/progress_bar.h"
#include "util/timer.h"

namespace hscloc {
namespace {

namespace fs = std::filesystem;

// Names already in an existing output file (a resumed run skips them).
std::unordered_set<std::string> NamesIn(const fs::path& path) {
  std::unordered_set<std::string> names;
  std::ifstream file(path);
  std::string line;
  while (std::getline(file, line)) {
    const size_t end = line.find(' ');
    if (end != std::string::npos && end > 0) names.insert(line.substr(0, end));
  }
  return names;
}

// Drops a half-written last line that an interrupted run may have left.
void TruncateToLastFullLine(const fs::path& path) {
  if (!fs::exists(path)) return;
  std::string text;
  {
    std::ifstream file(path, std::ios::binary);
    text.assign(std::istreambuf_iterator<char>(file), std::istreambuf_iterator<char>());
  }
  if (text.empty() || text.back() == '\n') return;
  const size_t last_newline = text.rfind('\n');
  text.resize(last_newline == std::string::npos ? 0 : last_newline + 1);
  std::ofstream(path, std::ios::binary | std::ios::trunc) << text;
}

void CheckInputsOf(const std::vector<QueryWithIntrinsics>& queries, const FeatureReader& features,
                   const GlobalDescriptorMap* global_descriptors) {
  for (const QueryWithIntrinsics& query : queries) {
    if (!features.HasImage(query.name)) {
      ThrowInvalidArgument("{}: no features for query '{}'", features.path().string(), query.name);
    }
    if (global_descriptors != nullptr && !global_descriptors->count(query.name)) {
      ThrowInvalidArgument("no global descriptor for query '{}'", query.name);
    }
  }
}

// The submission and the failure list, both appended to or truncated, written under one lock.
class SubmissionWriter {
 public:
  SubmissionWriter(const fs::path& out, const fs::path& failures_path, const fs::path& timings_path,
                   bool append) {
    if (!out.parent_path().empty()) fs::create_directories(out.parent_path());
    const auto mode = std::ios::out | (append ? std::ios::app : std::ios::trunc);
    submission_.open(out, mode);
    failures_.open(failures_path, mode);
    if (!submission_ || !failures_) ThrowInvalidArgument("cannot write {}", out.string());
    if (timings_path.empty()) return;
    if (!timings_path.parent_path().empty()) fs::create_directories(timings_path.parent_path());
    const bool has_header = append && fs::exists(timings_path) && fs::file_size(timings_path) > 0;
    timings_.open(timings_path, mode);
    if (!timings_) ThrowInvalidArgument("cannot write {}", timings_path.string());
    if (!has_header) {
      timings_ << "name,localized,keypoints,rounds,inliers,ransac_samples";
      for (const StageField& field : kStageFields) timings_ << ',' << field.name << "_ms";
      timings_ << '\n' << std::flush;
    }
  }

  // A failed query still gets a line (the top-1 retrieved image's pose), so that the submission
  // is complete; the failures file says which and why.
  void Write(const std::string& basename, const PoseResult& result, int64_t num_keypoints) {
    submission_ << FormatPoseLine(basename, result.cam_from_world) << std::flush;
    if (timings_.is_open()) {
      // The samples drawn do not depend on the machine's load, as the milliseconds do.
      int64_t ransac_samples = 0;
      for (const LocalizationCandidate& candidate : result.candidates) {
        ransac_samples += candidate.ransac_samples;
      }
      timings_ << fmt::format("{},{},{},{},{},{}", basename, result.success ? 1 : 0, num_keypoints,
                              result.timings.rounds, result.num_inliers, ransac_samples);
      for (const StageField& field : kStageFields) {
        timings_ << fmt::format(",{:.3f}", result.timings.*field.milliseconds);
      }
      timings_ << '\n' << std::flush;
    }
    if (!result.success) {
      failures_ << basename << ' ' << result.failure_reason << '\n' << std::flush;
    }
  }

 private:
  std::ofstream submission_;
  std::ofstream failures_;
  std::ofstream timings_;  // open only when the run asked for its timings
};

}  // namespace

LocalizationQuery LoadQuery(const QueryWithIntrinsics& entry, const FeatureReader& features,
                            const GlobalDescriptorMap* global_descriptors) {
  ImageFeatures image = features.Read(entry.name);
  LocalizationQuery query{entry.name, entry.camera, std::move(image.keypoints),
                          std::move(image.descriptors), std::nullopt};
  if (global_descriptors != nullptr) {
    const auto found = global_descriptors->find(entry.name);
    if (found == global_descriptors->end()) {
      ThrowInvalidArgument("no global descriptor for query '{}'", entry.name);
    }
    query.global_descriptor = found->second;
  }
  return query;
}

std::vector<LocalizationQuery> LoadQueries(const fs::path& list, const FeatureReader& features,
                                           const GlobalDescriptorMap* global_descriptors,
                                           size_t limit) {
  std::vector<LocalizationQuery> queries;
  for (const QueryWithIntrinsics& entry : ReadQueryList(list)) {
    if (queries.size() == limit) break;
    if (!features.HasImage(entry.name)) {
      ThrowInvalidArgument("{}: query '{}' of {} has no features", features.path().string(),
                           entry.name, list.string());
    }
    queries.push_back(LoadQuery(entry, features, global_descriptors));
  }
  return queries;
}

void QueryListRunOptions::Check() const {
  if (out.empty()) ThrowInvalidArgument("QueryListRunOptions.out is empty");
}

QueryListRunSummary RunQueryList(const Localizer& localizer,
                                 const std::vector<QueryWithIntrinsics>& queries,
                                 const FeatureReader& features,
                                 const GlobalDescriptorMap* global_descriptors,
                                 const QueryListRunOptions& options) {
  options.Check();
  CheckInputsOf(queries, features, global_descriptors);
  QueryListRunSummary summary;
  summary.num_queries = queries.size();
  summary.failures_path = options.out.string() + ".failures.txt";
  std::unordered_set<std::string> done;
  if (options.resume) {
    TruncateToLastFullLine(options.out);
    TruncateToLastFullLine(summary.failures_path);
    done = NamesIn(options.out);
  }
  std::vector<size_t> pending;
  for (size_t i = 0; i < queries.size(); ++i) {
    if (!done.count(ImageBasename(queries[i].name))) pending.push_back(i);
  }
  summary.num_skipped = queries.size() - pending.size();
  SubmissionWriter writer(options.out, summary.failures_path, options.timings_out, options.resume);

  // Queries run in parallel, each on one core: the network's products are too small to split
  // well across cores, while whole queries are independent.
  summary.num_threads =
      std::min<int>(ResolveNumThreads(options.num_threads), std::max<size_t>(pending.size(), 1));
  SetComputeThreads(1);
  ProgressBar progress(
      "localize", pending.size(),
      options.show_progress ? ProgressBar::Display::kAuto : ProgressBar::Display::kNever);
  std::mutex mutex;
  std::atomic<size_t> next{0};
  std::exception_ptr error;
  const Timer timer;
  const auto worker = [&] {
    for (size_t i = next++; i < pending.size(); i = next++) {
      try {
        const QueryWithIntrinsics& entry = queries[pending[i]];
        const LocalizationQuery query = LoadQuery(entry, features, global_descriptors);
        const PoseResult result = localizer.Localize(query);
        std::lock_guard<std::mutex> lock(mutex);
        writer.Write(ImageBasename(entry.name), result, query.keypoints.rows());
        ++(result.success ? summary.num_localized : summary.num_failed);
        summary.timings.Add(result.timings);
        const auto voted = [](const LocalizationCandidate& candidate) {
          return candidate.source == CandidateSource::kPointVotes;
        };
        summary.num_with_votes +=
            std::any_of(result.candidates.begin(), result.candidates.end(), voted);
        summary.num_won_by_votes +=
            result.success && voted(result.candidates[result.best_candidate]);
        summary.num_won_by_nearest_points +=
            result.success &&
            result.candidates[result.best_candidate].source == CandidateSource::kNearestPoints;
        progress.SetStatus(
            fmt::format("{} localized, {} failed", summary.num_localized, summary.num_failed));
        progress.Advance();
      } catch (...) {
        std::lock_guard<std::mutex> lock(mutex);
        if (!error) error = std::current_exception();
        next = pending.size();
      }
    }
  };
  std::vector<std::thread> threads;
  for (int t = 1; t < summary.num_threads; ++t) threads.emplace_back(worker);
  worker();
  for (std::thread& thread : threads) thread.join();
  progress.Finish();
  if (error) std::rethrow_exception(error);
  summary.seconds = timer.ElapsedSeconds();
  return summary;
}

}  // namespace hscloc
