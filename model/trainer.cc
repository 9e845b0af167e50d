#include "model/trainer.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <limits>
#include <memory>
#include <numeric>
#include <optional>

#include "map/map_bundle.h"
#include "model/lazy_adam.h"
#include "model/network_decoding.h"
#include "model/network_module.h"
#include "model/point_candidates.h"
#include "model/point_prototypes.h"
#include "model/training_batch.h"
#include "model/training_checkpoint.h"
#include "model/training_schedule.h"
#include "util/check.h"
#include "util/memory.h"
#include "util/progress_bar.h"
#include "util/random.h"
#include "util/timer.h"

namespace hscloc {
namespace {

NetworkShape TrainedNetworkShape(const Scene& scene, const LabelTree& tree,
                                 const TrainerOptions& options,
                                 const std::vector<uint32_t>& training) {
  NetworkShape shape = NetworkShape::ForTree(static_cast<int>(scene.Dimension()), tree,
                                             static_cast<int>(scene.NumImages()));
  if (options.network.pooled_point_rows) {
    shape.point_row_offsets = PointRowOffsets(scene, training, tree, options.point_prototypes);
  }
  return shape;
}

NetworkOptions TrainedNetworkOptions(const TrainerOptions& options) {
  NetworkOptions network = options.network;
  network.masked_decoding = options.visibility_softmax || network.pooled_point_rows;
  return network;
}

void SetLearningRate(torch::optim::Adam& optimizer, double rate) {
  for (torch::optim::OptimizerParamGroup& group : optimizer.param_groups()) {
    static_cast<torch::optim::AdamOptions&>(group.options()).lr(rate);
  }
}

std::string FormatAccuracies(const std::vector<double>& accuracies) {
  std::string text;
  for (const double accuracy : accuracies) {
    text += fmt::format("{}{:.3f}", text.empty() ? "" : "/", accuracy);
  }
  return text;
}

// A batch's loss (the sum of the levels' cross-entropies) and each level's teacher-forced
// accuracy (1 where the level has no choice).
struct BatchLoss {
  torch::Tensor loss;
  std::vector<torch::Tensor> accuracies;
};

// One TrainNetwork call: the network, its optimizers, the state a checkpoint keeps, and the
// training loop. It lives only for that call, so it holds the scene, tree and options by
// reference.
class Trainer {
 public:
  // Creates the network from the seed, or restores it from the checkpoint (options.resume).
  Trainer(const Scene& scene, const LabelTree& tree, const TrainerOptions& options,
          std::vector<uint32_t> training);

  // Trains until the budget is spent; the result holds the network to keep.
  TrainingResult Run();

 private:
  // Setup, in the order the constructor runs it; `checkpoint` is null without a resume.
  void CreateOrRestoreNetwork(CheckpointReader* checkpoint);
  void CreateOptimizers(CheckpointReader* checkpoint);
  void PrepareVisibilityAndCheckSample();
  // One optimizer step on the current iteration's batch; advances the iteration.
  void Step();
  BatchLoss Loss(const Batch& batch);
  // Appends the means since the last entry to the log.
  void FlushLog(int64_t iteration);
  bool CheckDue() const;
  void CheckHeldOut();
  void KeepAsBest(double accuracy);
  void WriteSnapshot() const;
  bool StopRequested() const {
    return options_.stop_requested != nullptr && options_.stop_requested->load();
  }
  void BankElapsedTime();
  void WriteCheckpoint();
  // After the loop: the last log entry, check and checkpoint, and the network to return.
  TrainingResult Finish();
  bool RestoreBestNetwork();
  bool MeasurablyBelowBest(double accuracy) const;
  // TrainerOptions::patience: the best check long enough behind, every later one measurably below.
  bool OutOfPatience();
  TrainingResult Result(bool restored_best);
  bool Converged() const;
  double Elapsed() const { return state_.seconds_before + timer_.ElapsedSeconds(); }
  double Progress() const { return budget_.Progress(state_.iteration, Elapsed()); }

  const Scene& scene_;
  const LabelTree& tree_;
  const TrainerOptions& options_;
  // options_.network, with masked decoding where the training's softmax was the visible one.
  const NetworkOptions network_options_;
  const torch::Device device_;
  const NetworkShape shape_;
  const int levels_;
  const std::vector<uint32_t> training_;  // the training observations
  SampleOrder order_;                     // and the order the iterations take them in
  TrainingBudget budget_;
  TrainingState state_;
  std::optional<Network> network_;
  HscNet module_{nullptr};
  std::optional<torch::optim::Adam> optimizer_;
  std::vector<LazyAdamTable> lazy_;
  Visibility visibility_;
  std::unique_ptr<NodeVisibilityMasks> node_masks_;
  std::unique_ptr<PointCandidates> point_candidates_;  // pooled point rows
  int finest_level_with_choice_ = -1;
  std::vector<uint32_t> check_sample_;
  bool checking_ = false;  // held-out checks are due (evaluations, and a sample to check)
  std::optional<ProgressBar> progress_;
  Timer timer_;
  // Sums since the last log entry, kept on the device so that no iteration waits for a copy.
  torch::Tensor sums_;
  int64_t iterations_in_sums_ = 0;
  double learning_rate_ = 0;  // the last step's
  std::string check_status_;  // the last check's, shown after the loss
  bool stopped_early_ = false;
};

Trainer::Trainer(const Scene& scene, const LabelTree& tree, const TrainerOptions& options,
                 std::vector<uint32_t> training)
    : scene_(scene),
      tree_(tree),
      options_(options),
      network_options_(TrainedNetworkOptions(options)),
      device_(TorchDevice(options.device)),
      shape_(TrainedNetworkShape(scene, tree, options, training)),
      levels_(shape_.levels),
      training_(training),
      order_(std::move(training), options.seed) {
  budget_ = BudgetOf(options, order_.size());
  std::optional<CheckpointReader> checkpoint;
  if (options.resume && !options.checkpoint_path.empty() &&
      std::filesystem::exists(options.checkpoint_path)) {
    checkpoint.emplace(options.checkpoint_path, device_);
  }
  CheckpointReader* resume_from = checkpoint ? &*checkpoint : nullptr;
  CreateOrRestoreNetwork(resume_from);
  CreateOptimizers(resume_from);
  PrepareVisibilityAndCheckSample();
  if (point_candidates_ != nullptr && resume_from == nullptr) {
    InitializePointRowsFromDescriptors(scene_, training_, *point_candidates_,
                                       network_options_.descriptor_shortcut, module_->point_rows);
  }
}

void Trainer::CreateOrRestoreNetwork(CheckpointReader* checkpoint) {
  if (checkpoint != nullptr) {
    network_.emplace(checkpoint->ReadNetwork(shape_, network_options_, options_.device));
    state_ = checkpoint->ReadState(levels_, options_.seed);
  } else {
    network_.emplace(shape_, network_options_, options_.seed);
    network_->SetDevice(options_.device);
  }
  module_ = NetworkInternals::Module(*network_);
  module_->train();
}

void Trainer::CreateOptimizers(CheckpointReader* checkpoint) {
  // The per-node and per-point tables go to lazy Adam (sparse gradients), everything else to dense
  // Adam. On the aachen preset the finest level's conditioning embeddings alone are 61 M numbers:
  // a dense gradient and Adam step over them cost more than the rest of a step
  // (docs/decisions.md).
  std::vector<torch::Tensor> dense_parameters;
  for (Level& level : module_->levels) {
    level->SetSparseNodeRows(options_.sparse_node_updates && level->HasNodeOutput());
  }
  for (const auto& item : module_->named_parameters()) {
    const bool node_rows = item.key().find("node_rows") != std::string::npos ||
                           item.key().find("point_rows") != std::string::npos ||
                           item.key().find("node_embedding") != std::string::npos;
    if (node_rows && options_.sparse_node_updates) {
      lazy_.push_back(LazyAdamTable::Of(item.value()));
    } else {
      dense_parameters.push_back(item.value());
    }
  }
  optimizer_.emplace(dense_parameters, torch::optim::AdamOptions(options_.learning_rate));
  if (checkpoint != nullptr) checkpoint->RestoreOptimizers(*optimizer_, lazy_);
}

void Trainer::PrepareVisibilityAndCheckSample() {
  // The visibility of every database image, per tree node, for the visibility softmax and the
  // held-out checks (masked decoding, as the localizer's visibility filter sees it).
  visibility_ = Visibility::FromObservations(scene_.NumImages(), scene_.NumPoints(),
                                             scene_.observation_image_indices,
                                             scene_.observation_point_indices);
  std::vector<uint32_t> all_images(scene_.NumImages());
  std::iota(all_images.begin(), all_images.end(), 0u);
  if (network_options_.pooled_point_rows) {
    point_candidates_ = std::make_unique<PointCandidates>(tree_, &visibility_, all_images,
                                                          &shape_.point_row_offsets);
    for (int level = 0; level < levels_; ++level) {
      if (tree_.LevelHasChoice(level)) finest_level_with_choice_ = level;
    }
  } else if (options_.visibility_softmax) {
    node_masks_ = std::make_unique<NodeVisibilityMasks>(all_images, tree_, visibility_);
  }
  // The held-out sample of the checks: evenly spaced over the held-out observations.
  const std::vector<uint32_t> held_out =
      HeldOutObservations(scene_, options_.holdout_fraction, options_.holdout_seed);
  const size_t wanted = std::min<size_t>(held_out.size(), options_.evaluation_observations);
  for (size_t i = 0; i < wanted; ++i) {
    check_sample_.push_back(held_out[i * held_out.size() / wanted]);
  }
  checking_ = options_.evaluations > 0 && !check_sample_.empty();
}

TrainingResult Trainer::Run() {
  // The bar counts this run's steps (a resumed run's rate and ETA would otherwise include the
  // steps before the resume).
  const int64_t budget_iterations = budget_.iterations;
  progress_.emplace(
      "train",
      budget_iterations > 0 ? budget_iterations - std::min(state_.iteration, budget_iterations) : 0,
      options_.show_progress ? ProgressBar::Display::kAuto : ProgressBar::Display::kNever);
  if (budget_.seconds > 0) progress_->SetTimeLimit(budget_.seconds - state_.seconds_before);
  timer_.Restart();
  sums_ = torch::zeros({1 + levels_}, torch::TensorOptions().device(device_));
  learning_rate_ = ScheduledLearningRate(options_, Progress());
  // The descriptor shortcut starts as the nearest-class-mean matcher: a check before the first
  // step lets early stopping keep it where training would only lose held-out accuracy.
  if (network_options_.descriptor_shortcut && state_.iteration == 0) CheckHeldOut();
  while (!budget_.Spent(state_.iteration, Elapsed()) && !StopRequested() && !OutOfPatience()) {
    Step();
    progress_->Advance();
    if (state_.iteration % options_.log_every_iterations == 0) FlushLog(state_.iteration);
    if (CheckDue()) CheckHeldOut();
    if (!options_.checkpoint_path.empty() &&
        state_.iteration % options_.checkpoint_every_iterations == 0) {
      BankElapsedTime();
      WriteCheckpoint();
    }
  }
  return Finish();
}

void Trainer::Step() {
  learning_rate_ = ScheduledLearningRate(options_, Progress());
  SetLearningRate(*optimizer_, learning_rate_);
  const BatchContext context{scene_,
                             tree_,
                             options_,
                             node_masks_.get(),
                             network_options_.node_output_dim > 0,
                             point_candidates_.get()};
  const Batch batch = MakeBatch(context, order_, state_.iteration, device_);
  BatchLoss loss = Loss(batch);
  optimizer_->zero_grad();
  loss.loss.backward();
  optimizer_->step();
  for (LazyAdamTable& table : lazy_) table.Step(learning_rate_);
  std::vector<torch::Tensor> statistics = std::move(loss.accuracies);
  statistics.insert(statistics.begin(), loss.loss.detach());
  sums_ += torch::stack(statistics);
  ++iterations_in_sums_;
  ++state_.iteration;
}

BatchLoss Trainer::Loss(const Batch& batch) {
  const torch::Tensor descriptors = NormalizeRows(batch.descriptors);
  BatchLoss result{torch::zeros({}, torch::TensorOptions().device(device_)), {}};
  torch::Tensor trunk;  // a shared trunk's output, once per batch
  for (int level = 0; level < levels_; ++level) {
    if (!tree_.LevelHasChoice(level)) {
      // Nothing to learn: Predict takes the only child without running this level.
      result.accuracies.push_back(torch::ones({}, torch::TensorOptions().device(device_)));
      continue;
    }
    Level& level_module = module_->levels[level];
    const torch::Tensor prefix = batch.labels.narrow(1, 0, static_cast<int64_t>(level));
    if (!level_module->BorrowsTrunk() || !trunk.defined()) trunk = level_module->Trunk(descriptors);
    const torch::Tensor features =
        level_module->FeaturesOfTrunk(trunk, batch.images, prefix, batch.parent_nodes[level]);
    torch::Tensor logits;
    if (level_module->IsPooled()) {
      // The finest level with a choice owns the point rows; coarser levels pool over them as
      // they are, learning only to map a descriptor near its point's row. Their gradients, a
      // pull on every point of the true child and a push on all the others, would otherwise
      // swamp each row's own signal (Adam scales every row's update to the same size).
      const bool owns_rows = level == finest_level_with_choice_;
      logits = PooledPointLogits(level_module->Project(features, descriptors),
                                 owns_rows ? module_->point_rows : module_->point_rows.detach(),
                                 batch.candidates[level], tree_.branching(), Pooling::kLogSumExp,
                                 options_.sparse_node_updates);
    } else {
      logits = level_module->Logits(features, batch.child_nodes[level]);
    }
    if (batch.allowed[level].defined()) {
      logits = logits.masked_fill(batch.allowed[level].logical_not(),
                                  -std::numeric_limits<float>::infinity());
    }
    const torch::Tensor target =
        batch.targets[level].defined() ? batch.targets[level] : batch.labels.select(1, level);
    result.loss = result.loss + torch::nn::functional::cross_entropy(logits, target);
    result.accuracies.push_back(logits.detach().argmax(1).eq(target).to(torch::kFloat32).mean());
  }
  return result;
}

void Trainer::FlushLog(int64_t iteration) {
  if (iterations_in_sums_ == 0) return;
  const torch::Tensor means = (sums_ / static_cast<double>(iterations_in_sums_)).to(torch::kCPU);
  TrainingLogEntry entry{iteration, Elapsed(), learning_rate_, means[0].item<double>(), {}};
  for (int level = 0; level < levels_; ++level) {
    entry.level_accuracies.push_back(means[1 + level].item<double>());
  }
  progress_->SetStatus(fmt::format("loss {:.3f} acc {}{}", entry.loss,
                                   FormatAccuracies(entry.level_accuracies), check_status_));
  state_.log.push_back(std::move(entry));
  sums_.zero_();
  iterations_in_sums_ = 0;
}

bool Trainer::CheckDue() const {
  const size_t checks_after_start =
      std::count_if(state_.checks.begin(), state_.checks.end(),
                    [](const HeldOutCheck& check) { return check.iteration > 0; });
  const double next = static_cast<double>(checks_after_start + 1) / options_.evaluations;
  return checking_ && next < 1 && Progress() >= next;
}

// A held-out check: masked point accuracy on the sample; keeps the best parameters.
void Trainer::CheckHeldOut() {
  if (!checking_) return;
  if (!state_.checks.empty() && state_.checks.back().iteration == state_.iteration) return;
  const double seconds_before_check = Elapsed();
  module_->eval();
  const NetworkEvaluation evaluation =
      EvaluateNetwork(*network_, scene_, tree_, check_sample_, &visibility_);
  module_->train();
  state_.checks.push_back({state_.iteration, seconds_before_check, evaluation.leaf_accuracy});
  if (!options_.snapshot_dir.empty()) WriteSnapshot();
  if (evaluation.leaf_accuracy > state_.best_accuracy) KeepAsBest(evaluation.leaf_accuracy);
  check_status_ = fmt::format(" held-out {:.1f}% (best {:.1f}%)", 100 * evaluation.leaf_accuracy,
                              100 * state_.best_accuracy);
  progress_->SetStatus(check_status_);
}

void Trainer::WriteSnapshot() const {
  std::filesystem::create_directories(options_.snapshot_dir);
  const std::filesystem::path path = options_.snapshot_dir / SnapshotFileName(state_.iteration);
  // A reader never sees half a snapshot.
  const std::filesystem::path partial = path.string() + ".partial";
  {
    std::ofstream stream(partial, std::ios::binary);
    network_->Save(stream);
    if (!stream.flush()) ThrowInvalidArgument("cannot write the snapshot {}", partial.string());
  }
  std::filesystem::rename(partial, path);
}

void Trainer::KeepAsBest(double accuracy) {
  state_.best_accuracy = accuracy;
  state_.best_iteration = state_.iteration;
  if (options_.keep_best) {
    torch::NoGradGuard no_grad;
    state_.best_parameters.clear();
    for (const torch::Tensor& parameter : module_->parameters()) {
      state_.best_parameters.push_back(parameter.detach().clone());
    }
  }
}

// Adds the time since the timer's start to the state's (what a checkpoint records).
void Trainer::BankElapsedTime() {
  state_.seconds_before = Elapsed();
  timer_.Restart();
}

void Trainer::WriteCheckpoint() {
  SaveCheckpoint(options_.checkpoint_path, *network_, *optimizer_, lazy_, state_, options_.seed);
}

TrainingResult Trainer::Finish() {
  FlushLog(state_.iteration);
  CheckHeldOut();
  progress_->Finish();
  BankElapsedTime();
  if (!options_.checkpoint_path.empty()) WriteCheckpoint();
  module_->eval();
  for (Level& level : module_->levels) level->SetSparseNodeRows(false);
  const bool restored_best = RestoreBestNetwork();
  return Result(restored_best);
}

bool Trainer::MeasurablyBelowBest(double accuracy) const {
  return MeasurablyBelow(accuracy, state_.best_accuracy, check_sample_.size());
}

bool Trainer::OutOfPatience() {
  if (!options_.keep_best || options_.patience <= 0 || state_.best_parameters.empty()) return false;
  const auto best = std::find_if(
      state_.checks.begin(), state_.checks.end(),
      [&](const HeldOutCheck& check) { return check.iteration == state_.best_iteration; });
  if (best == state_.checks.end() || best + 1 == state_.checks.end()) return false;
  const double waited = Progress() - budget_.Progress(best->iteration, best->seconds);
  const bool all_below = std::all_of(best + 1, state_.checks.end(), [&](const HeldOutCheck& check) {
    return MeasurablyBelowBest(check.point_accuracy);
  });
  stopped_early_ = waited >= options_.patience && all_below;
  return stopped_early_;
}

// Early stopping: the best held-out network, where a later one was worse.
bool Trainer::RestoreBestNetwork() {
  if (!options_.keep_best || state_.best_parameters.empty() || state_.checks.empty()) return false;
  const bool restore = ReturnsBestNetwork(state_.checks, check_sample_.size());
  if (restore) {
    torch::NoGradGuard no_grad;
    const std::vector<torch::Tensor> parameters = module_->parameters();
    for (size_t i = 0; i < parameters.size(); ++i) parameters[i].copy_(state_.best_parameters[i]);
  }
  return restore;
}

TrainingResult Trainer::Result(bool restored_best) {
  const size_t num_training = order_.size();
  TrainingResult result{std::move(*network_),
                        state_.iteration,
                        state_.seconds_before,
                        0,
                        {},
                        num_training,
                        scene_.NumObservations() - num_training,
                        std::move(state_.log),
                        state_.checks};
  if (!result.log.empty()) {
    result.final_loss = result.log.back().loss;
    result.final_level_accuracies = result.log.back().level_accuracies;
  }
  if (!state_.checks.empty()) {
    result.best_iteration = restored_best ? state_.best_iteration : state_.checks.back().iteration;
    result.best_held_out_accuracy =
        restored_best ? state_.best_accuracy : state_.checks.back().point_accuracy;
    result.converged = Converged();
  }
  result.interrupted = StopRequested() && !budget_.Spent(state_.iteration, state_.seconds_before);
  result.stopped_early = stopped_early_;
  return result;
}

// Converged: the last quarter of the budget gained less than 5 % of the accuracy reached.
bool Trainer::Converged() const {
  const double final_progress = budget_.Progress(state_.iteration, state_.seconds_before);
  std::vector<double> accuracies, progress;
  for (const HeldOutCheck& check : state_.checks) {
    accuracies.push_back(check.point_accuracy);
    progress.push_back(budget_.Progress(check.iteration, check.seconds) / final_progress);
  }
  return HeldOutConverged(accuracies, progress);
}

}  // namespace

void DescriptorAugmentationOptions::Check() const {
  THROW_CHECK_MSG(noise_norm >= 0 && std::isfinite(noise_norm),
                  "DescriptorAugmentationOptions.noise_norm = {}", noise_norm);
  THROW_CHECK_MSG(dimension_dropout >= 0 && dimension_dropout < 1,
                  "DescriptorAugmentationOptions.dimension_dropout = {}", dimension_dropout);
}

void TrainerOptions::Check() const {
  network.Check();
  THROW_CHECK_MSG(point_prototypes >= 1 && point_prototypes <= kMaxPointPrototypes,
                  "TrainerOptions.point_prototypes = {} (1 .. {})", point_prototypes,
                  kMaxPointPrototypes);
  augmentation.Check();
  THROW_CHECK_MSG(max_iterations >= 0, "TrainerOptions.max_iterations = {}", max_iterations);
  THROW_CHECK_MSG(max_minutes >= 0 && std::isfinite(max_minutes), "TrainerOptions.max_minutes = {}",
                  max_minutes);
  THROW_CHECK_MSG(epochs >= 0 && std::isfinite(epochs), "TrainerOptions.epochs = {}", epochs);
  THROW_CHECK_MSG(warmup_fraction >= 0 && warmup_fraction < 1,
                  "TrainerOptions.warmup_fraction = {}", warmup_fraction);
  THROW_CHECK_MSG(final_rate_fraction > 0 && final_rate_fraction <= 1,
                  "TrainerOptions.final_rate_fraction = {}", final_rate_fraction);
  THROW_CHECK_MSG(evaluations >= 0, "TrainerOptions.evaluations = {}", evaluations);
  THROW_CHECK_MSG(patience >= 0 && patience <= 1, "TrainerOptions.patience = {} (0 .. 1)",
                  patience);
  THROW_CHECK_MSG(evaluation_observations > 0, "TrainerOptions.evaluation_observations = {}",
                  evaluation_observations);
  THROW_CHECK_MSG(batch_size > 0, "TrainerOptions.batch_size = {}", batch_size);
  THROW_CHECK_MSG(learning_rate > 0 && std::isfinite(learning_rate),
                  "TrainerOptions.learning_rate = {}", learning_rate);
  for (const double fraction : halving_fractions) {
    THROW_CHECK_MSG(fraction > 0 && fraction < 1, "TrainerOptions.halving_fractions: {}", fraction);
  }
  THROW_CHECK_MSG(image_dropout >= 0 && image_dropout <= 1, "TrainerOptions.image_dropout = {}",
                  image_dropout);
  THROW_CHECK_MSG(holdout_fraction >= 0 && holdout_fraction < 1,
                  "TrainerOptions.holdout_fraction = {}", holdout_fraction);
  THROW_CHECK_MSG(checkpoint_every_iterations > 0,
                  "TrainerOptions.checkpoint_every_iterations = {}", checkpoint_every_iterations);
  THROW_CHECK_MSG(log_every_iterations > 0, "TrainerOptions.log_every_iterations = {}",
                  log_every_iterations);
}

std::string TrainingResult::LogCsv() const {
  std::string csv = "iteration,seconds,learning_rate,loss";
  const size_t levels = log.empty() ? 0 : log.front().level_accuracies.size();
  for (size_t level = 1; level <= levels; ++level) csv += fmt::format(",accuracy_level{}", level);
  csv += '\n';
  for (const TrainingLogEntry& entry : log) {
    csv += fmt::format("{},{:.3f},{:.3g},{:.6f}", entry.iteration, entry.seconds,
                       entry.learning_rate, entry.loss);
    for (const double accuracy : entry.level_accuracies) csv += fmt::format(",{:.6f}", accuracy);
    csv += '\n';
  }
  return csv;
}

std::string SnapshotFileName(int64_t iteration) {
  return fmt::format("network-{:08d}.pt", iteration);
}

TrainingResult TrainNetwork(const Scene& scene, const LabelTree& tree,
                            const TrainerOptions& options) {
  options.Check();
  if (tree.NumPoints() != scene.NumPoints()) {
    ThrowInvalidArgument("train: label tree of {} points, scene of {}", tree.NumPoints(),
                         scene.NumPoints());
  }
  std::vector<uint32_t> training;
  for (uint32_t i = 0; i < scene.NumObservations(); ++i) {
    if (!IsHeldOutObservation(i, options.holdout_fraction, options.holdout_seed)) {
      training.push_back(i);
    }
  }
  if (training.empty()) ThrowInvalidArgument("train: the scene has no training observations");
  SetComputeThreads(options.num_threads);
  KeepLargeFreedMemoryForReuse();
  Trainer trainer(scene, tree, options, std::move(training));
  return trainer.Run();
}

}  // namespace hscloc
