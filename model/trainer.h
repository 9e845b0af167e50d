// Training and evaluation of the hierarchical classification network (model/network.h) on a
// map's observations, as in Li et al., CVPR 2020 (classification-only variant): every observation
// (descriptor, database image, observed point) is a sample whose targets are the point's label
// path; the generators see the ground-truth coarser labels and the observation's own image
// (teacher forcing); the loss is the sum of the per-level cross-entropies; Adam with the learning
// rate halved late in training.
//
// Determinism: the data order and the augmentation are drawn from counter-based random streams
// addressed by (seed, iteration, row), and the weights are initialized from the seed, so the same
// scene, options, seed, device and thread count give bit-identical weights, and a run resumed
// from a checkpoint continues exactly as the uninterrupted run would have. A time budget makes the
// number of iterations (and the learning-rate schedule) depend on the machine.
#pragma once

#include <atomic>
#include <cstdint>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "map/label_tree.h"
#include "map/visibility.h"
#include "model/network.h"
#include "scene/scene.h"

namespace hscloc {

// Noise in descriptor space, so that the network sees descriptors as they vary between views
// (lighting, viewpoint, night) rather than the few it was given per point.
struct DescriptorAugmentationOptions {
  bool enabled = true;
  // Expected L2 norm of the isotropic Gaussian noise added to the unit descriptor.
  double noise_norm = 0.3;
  // Probability of zeroing each descriptor dimension (before renormalizing).
  double dimension_dropout = 0.1;
  void Check() const;
};

// How the learning rate moves over the budget.
enum class LearningRateSchedule {
  kHalving,   // constant, halved at halving_fractions of the budget (the paper's steps)
  kOneCycle,  // linear warm-up to learning_rate, then a cosine down to final_rate_fraction of it
};

struct TrainerOptions {
  NetworkOptions network;
  // Budgets: training stops at whichever is reached first; 0 disables one. All three 0: an
  // automatic budget in epochs from the map's size (DefaultEpochs).
  int64_t max_iterations = 0;
  double max_minutes = 0;
  double epochs = 0;  // passes over the training observations
  // Observations per step: on CPU, batches of 1024 train 3.4 times as many observations per second
  // as 256 (docs/decisions.md).
  int batch_size = 1024;
  double learning_rate = 3e-3;  // Adam, the peak of the one-cycle (docs/decisions.md)
  LearningRateSchedule schedule = LearningRateSchedule::kOneCycle;
  // One-cycle: fraction of the budget spent warming up, and the final rate over the peak.
  double warmup_fraction = 0.05;
  double final_rate_fraction = 0.02;
  // Halving schedule: fractions of the budget at which the learning rate halves.
  std::vector<double> halving_fractions = {0.5, 0.75, 0.9};
  // Each level's softmax only over the children whose subtree holds a point the sample's image
  // observes (what masked decoding chooses among); samples without an image see every child.
  // Worth 8 points of held-out accuracy on the city when decoded with the mask, but a network so
  // trained must be decoded with it: plain decoding loses most of its accuracy
  // (docs/decisions.md). The network records it (NetworkOptions::masked_decoding) and the
  // Localizer follows. Pooled point rows always train this way, whatever this says.
  bool visibility_softmax = false;
  // The per-node and per-point tables (output rows, point rows, conditioning embeddings) updated
  // row-wise (lazy Adam on the rows a batch touches) rather than by dense Adam over the whole
  // table every step.
  bool sparse_node_updates = true;
  // Held-out evaluations over the budget (masked point accuracy on up to
  // evaluation_observations held-out observations); with keep_best the best network is returned
  // when the last check fell below it by more than two standard errors of the check (early
  // stopping: more training never gives a measurably worse network). 0: none.
  int evaluations = 12;
  int64_t evaluation_observations = 3000;
  bool keep_best = true;
  // With keep_best: training ends once the best check is this fraction of the budget behind and
  // every check since fell below it by more than two standard errors, since the network it
  // returns is then that check's. On three of the four real sets' maps the network that starts
  // from the data (the descriptor shortcut) is never beaten, and the rest of the budget was
  // spent in vain (docs/decisions.md). 0: the whole budget.
  double patience = 0.25;
  DescriptorAugmentationOptions augmentation;
  // Probability of replacing a sample's image by the "no image" index, so that the network also
  // learns to classify without an image (the id-free ablation). It also regularizes: on maps with
  // few views per point the network leans less on memorized (image, descriptor) pairs
  // (docs/decisions.md).
  double image_dropout = 0.1;
  // Pooled point rows: up to this many rows per point (prototypes), each started from the point's
  // own training observations (model/point_prototypes.h). With more than one, the Localizer's
  // final pose matches the rows as nearest neighbour matches (localization/point_row_matches.h):
  // on Lund with XFeat, 64 (a row per view) brought the network's median position error from
  // 1.4-2.1x nearest neighbour's to 0.98-1.25x, for a larger bundle and a slower final pose
  // (docs/decisions.md, "The network on real photos"). `hscloc train` chooses it from the map
  // (DefaultPointPrototypes).
  int point_prototypes = 1;
  // Fraction of observations held out from training (deterministic in holdout_seed), for
  // EvaluateNetwork on data the network never saw.
  double holdout_fraction = 0.05;
  uint64_t holdout_seed = 0;
  uint64_t seed = 0;
  int num_threads = 0;  // <= 0: all cores
  ComputeDevice device = ComputeDevice::kCpu;
  // Checkpoint file (network, optimizer state, iteration, log); empty: no checkpoints.
  std::filesystem::path checkpoint_path;
  int64_t checkpoint_every_iterations = 2000;
  // Continue from checkpoint_path when it exists.
  bool resume = false;
  // Where each held-out check saves the network as it stands, as `network-<iteration>.pt` in the
  // bundle's archive format, for localization accuracy against training time; empty: none.
  std::filesystem::path snapshot_dir;
  int64_t log_every_iterations = 100;
  bool show_progress = true;
  // When set (by another thread or a signal handler), training ends after the current step as if
  // its budget were spent: the last check, the checkpoint and the best network are kept.
  const std::atomic<bool>* stop_requested = nullptr;
  void Check() const;
};

// Means over the iterations since the previous entry; accuracies are teacher-forced (each level
// given the true coarser labels) on the augmented training batches.
struct TrainingLogEntry {
  int64_t iteration = 0;
  double seconds = 0;
  double learning_rate = 0;
  double loss = 0;
  std::vector<double> level_accuracies;
};

// One held-out evaluation during training.
struct HeldOutCheck {
  int64_t iteration = 0;
  double seconds = 0;
  double point_accuracy = 0;  // masked decoding
};

struct TrainingResult {
  Network network;
  int64_t iterations = 0;
  double seconds = 0;  // including the time before a resume
  double final_loss = 0;
  std::vector<double> final_level_accuracies;
  size_t num_training_observations = 0;
  size_t num_held_out_observations = 0;
  std::vector<TrainingLogEntry> log;
  std::vector<HeldOutCheck> held_out_checks;
  // The returned network's iteration and held-out accuracy (keep_best), or the last ones.
  int64_t best_iteration = 0;
  double best_held_out_accuracy = -1;  // -1: never evaluated
  // HeldOutConverged over the held-out checks.
  bool converged = false;
  // Ended by TrainerOptions::stop_requested before the budget was spent.
  bool interrupted = false;
  // Ended by TrainerOptions::patience before the budget was spent.
  bool stopped_early = false;

  // "iteration,seconds,learning_rate,loss,accuracy_level1,..." and one line per entry.
  std::string LogCsv() const;
};

// The epochs an automatic budget trains for a map of this many training observations: fewer
// passes for larger maps, whose batches hold more distinct points, and far fewer for pooled point
// rows, which start from the data (docs/decisions.md).
double DefaultEpochs(size_t num_training_observations, const NetworkOptions& network);
// Maps with fewer points keep the paper's shared output layer (node_output_dim = 0).
inline constexpr size_t kMinPointsForNodeOutputRows = 10000;
// The width C = H of the default network on maps below kMinPointsForNodeOutputRows points.
inline constexpr int kSmallMapChannels = 128;
// The most rows per point TrainerOptions::point_prototypes allows.
inline constexpr int kMaxPointPrototypes = 64;
// Widths for a map of this many points and descriptors of this dimension: below
// kMinPointsForNodeOutputRows points the descriptor shortcut at C = H = kSmallMapChannels (a few
// views per point: the class means to start from, a small correction to learn); from there on
// pooled point rows, narrowing on large maps so that the bundle stays small (docs/decisions.md).
NetworkOptions DefaultNetworkOptions(size_t num_points, int descriptor_dim);
// The rows per point (TrainerOptions::point_prototypes) of a network with these options when
// none are asked for: a row per training view where the network starts from the data (the
// descriptor shortcut of a map below kMinPointsForNodeOutputRows points), one elsewhere. On Lund
// XFeat a row per view, its rows matched for the final pose, brought the median position error
// from 1.4-2.1x nearest neighbour's to 0.98-1.25x; with early stopping it trains in about as long
// as one row did before (docs/decisions.md).
int DefaultPointPrototypes(const NetworkOptions& network);
// The file a held-out check at `iteration` writes into TrainerOptions::snapshot_dir; names sort by
// iteration.
std::string SnapshotFileName(int64_t iteration);
// Whether a network with these output layers conditions on node embeddings by default: not with
// pooled point rows.
bool DefaultNodeConditioning(const NetworkOptions& options);

// Whether held-out checks (accuracies at their share of the budget, 0 to 1) show a converged
// training: the checks of the budget's last quarter beat every earlier one by less than 5 % of the
// best. A best check early in the budget with later ones worse is converged too: more of the same
// budget would not help. False with fewer than two checks.
bool HeldOutConverged(const std::vector<double>& accuracies, const std::vector<double>& progress);

// Whether `accuracy` is more than two standard errors of a check of `check_sample` observations
// below `best`: a drop the check can tell from sampling noise.
bool MeasurablyBelow(double accuracy, double best, size_t check_sample);

// Whether training hands back its best checked network rather than its last (with keep_best):
// where the last check is measurably below the best, or where the best is the untrained start
// (iteration 0) and no later check reached it. False without checks.
bool ReturnsBestNetwork(const std::vector<HeldOutCheck>& checks, size_t check_sample);

// Whether observation `index` belongs to the held-out fraction (a hash of index and seed).
bool IsHeldOutObservation(uint64_t index, double fraction, uint64_t seed);
// The held-out observation indices of a scene, ascending.
std::vector<uint32_t> HeldOutObservations(const Scene& scene, double fraction, uint64_t seed);

// Trains a network on the scene's observations that are not held out. Throws
// std::invalid_argument when the options are invalid, the tree does not match the scene, or a
// checkpoint to resume from belongs to another shape or options.
TrainingResult TrainNetwork(const Scene& scene, const LabelTree& tree,
                            const TrainerOptions& options);

struct NetworkEvaluation {
  size_t num_observations = 0;
  // Share of observations whose predicted label path is right up to level j (index j - 1),
  // each level conditioned on the labels predicted before it.
  std::vector<double> level_accuracies;
  // Share of observations whose predicted point is the observed point.
  double leaf_accuracy = 0;
  double seconds = 0;
};

// Predicts the observations' points, each conditioned on its own image (masked by the image's
// visibility lists when `visibility_mask` is given).
NetworkEvaluation EvaluateNetwork(const Network& network, const Scene& scene, const LabelTree& tree,
                                  const std::vector<uint32_t>& observation_indices,
                                  const Visibility* visibility_mask = nullptr);

// The nearest-class-mean matcher, the yardstick of a network's held-out accuracy: each point's
// class mean is the normalized mean of the unit descriptors of its observations outside
// `evaluated`, and each observation of `evaluated` goes to the point, among those its image
// observes, whose mean has the largest cosine with it. Levels count the predicted point's label
// path. A point whose every observation is evaluated has no mean and is never predicted.
NetworkEvaluation EvaluateNearestClassMean(const Scene& scene, const LabelTree& tree,
                                           const Visibility& visibility,
                                           const std::vector<uint32_t>& evaluated);

// Adds the network (map_blobs::kNetwork), the training log (map_blobs::kTrainingLog) and
// metadata "network" (shape, options, training summary, the evaluations given, and the entries of
// `notes`, such as what the network's matching costs) to an existing map bundle, atomically.
void WriteNetworkToBundle(
    const std::filesystem::path& bundle_dir, const TrainingResult& result,
    const TrainerOptions& options,
    const std::vector<std::pair<std::string, NetworkEvaluation>>& evaluations = {},
    const nlohmann::json& notes = nlohmann::json::object());

}  // namespace hscloc
