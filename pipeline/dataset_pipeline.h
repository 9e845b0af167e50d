// From a dataset's photos and map model to a submission, one resumable run:
//   features    OUT/features.h5     local features of every map image and query (hloc layout)
//   model       OUT/model/          a COLMAP model triangulated for them from the map's poses
//   map         OUT/map/            the map bundle (nearest-neighbour ready)
//   network     OUT/map/            the trained network added to the bundle (matcher hsc only)
//   submission  OUT/submission.txt  (matcher nn: OUT/submission-nn.txt), visuallocalization.net's
//                                   format; evaluated against the dataset's ground truth if any
// A step is skipped when its output is complete; a step's output appears under its name only once
// complete (it is written as <name>.partial, e.g. features.partial.h5, and renamed), so an
// interrupted run leaves nothing a rerun would trust. Features are written in chunks, and training
// checkpoints, so a rerun picks up an interrupted extraction or training where it stopped. A step
// that runs invalidates the outputs of the steps after it.
#pragma once

#include <atomic>
#include <cstdint>
#include <filesystem>
#include <iosfwd>
#include <optional>
#include <string>
#include <vector>

#include "features/feature_extractor.h"
#include "localization/localizer.h"
#include "localization/pose_evaluation.h"
#include "pipeline/dataset_layout.h"

namespace hscloc {

struct PipelineOptions {
  FeatureType feature = FeatureType::kXFeat;
  Matcher matcher = Matcher::kNetwork;
  // Training budget; both 0: `hscloc train`'s default budget for the map.
  int64_t max_iterations = 0;
  double max_minutes = 0;
  uint64_t seed = 0;
  int num_threads = 0;  // <= 0: all cores
  std::string colmap_executable = "colmap";
  bool show_progress = true;  // progress bars of the long steps, on stderr
  // When set (by a signal handler), the run stops at the next safe point: between chunks of
  // photos, or after the current training step with the training checkpointed. Nothing is
  // published for the step it stopped; a rerun resumes it.
  const std::atomic<bool>* stop_requested = nullptr;

  void Check() const;
};

struct PipelineStepReport {
  std::string name;
  bool skipped = false;      // its output was complete
  bool interrupted = false;  // stopped by PipelineOptions::stop_requested, nothing published
  double seconds = 0;
  std::string detail;  // what it made, one line
};

struct PipelineSummary {
  std::vector<PipelineStepReport> steps;
  std::filesystem::path submission;
  // Against the dataset's ground truth, per condition; empty without one.
  std::vector<ConditionAccuracy> accuracy;
  std::vector<QueryPoseError> errors;

  bool NothingToDo() const;
  // Whether a step was interrupted (the steps after it did not run).
  bool Interrupted() const;
};

// The submission's file name for a matcher.
std::string SubmissionFileName(Matcher matcher);

// Runs the steps for `dataset` into `out` (created), writing a line per step as it starts and as
// it ends to `log`; an interrupted run returns with the step marked. Throws std::invalid_argument,
// before anything is written, for a dataset in neither layout, photos the model or the query lists
// name but the folder lacks, or an `out` made by another dataset or feature.
PipelineSummary RunDatasetPipeline(const std::filesystem::path& dataset,
                                   const std::filesystem::path& out, const PipelineOptions& options,
                                   std::ostream& log);

}  // namespace hscloc
