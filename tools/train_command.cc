#include <fmt/format.h>

#include <atomic>
#include <iostream>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "localization/localization_map.h"
#include "localization/matcher_choice.h"
#include "model/network.h"
#include "model/trainer.h"
#include "tools/commands.h"
#include "tools/stop_signal.h"
#include "util/check.h"
#include "util/timer.h"

namespace hscloc {
namespace {

struct TrainArguments {
  std::string map_dir;
  std::string device = "cpu";
  std::string checkpoint;
  bool no_augment = false;
  bool eval = false;
  bool eval_only = false;
  bool paper = false;
  std::string conditioning;  // empty: from the output layers
  bool visibility_softmax = false;
  bool dense_node_updates = false;
  bool no_keep_best = false;
  std::string schedule;
  bool node_output_dim_given = false;
  bool channels_given = false;
  bool trunk_channels_given = false;
  bool point_prototypes_given = false;
  std::string output;  // shared, node, pooled, shortcut; empty: from the map's size
  std::string trunk;   // shared, per-level; empty: from the map's size
  TrainerOptions options;
};

void PrintEvaluation(const std::string& name, const NetworkEvaluation& evaluation) {
  std::string levels;
  for (const double accuracy : evaluation.level_accuracies) {
    levels += fmt::format(" {:6.2f}", 100 * accuracy);
  }
  std::cout << fmt::format("  {:<16}{:>9}  {} | {:6.2f}   ({})\n", name,
                           evaluation.num_observations, levels, 100 * evaluation.leaf_accuracy,
                           FormatDuration(evaluation.seconds));
}

std::vector<std::pair<std::string, NetworkEvaluation>> EvaluateHeldOut(const Network& network,
                                                                       const LocalizationMap& map,
                                                                       double fraction,
                                                                       uint64_t seed) {
  std::vector<uint32_t> held_out = HeldOutObservations(map.scene(), fraction, seed);
  // Unmasked decoding of a pooled network scores every point of the map per observation: on the
  // aachen preset (1.5 M points, 231 k held out) the whole set would take longer than training.
  // An evenly spaced sample of 20,000 measures the accuracy to about +-0.3 %.
  constexpr size_t kMaxEvaluated = 20000;
  if (held_out.size() > kMaxEvaluated) {
    std::vector<uint32_t> sample(kMaxEvaluated);
    for (size_t i = 0; i < kMaxEvaluated; ++i) {
      sample[i] = held_out[i * held_out.size() / kMaxEvaluated];
    }
    held_out = std::move(sample);
  }
  std::vector<std::pair<std::string, NetworkEvaluation>> evaluations = {
      {"held_out", EvaluateNetwork(network, map.scene(), map.label_tree(), held_out)},
      {"held_out_masked",
       EvaluateNetwork(network, map.scene(), map.label_tree(), held_out, &map.visibility())},
      {"held_out_nearest_class_mean",
       EvaluateNearestClassMean(map.scene(), map.label_tree(), map.visibility(), held_out)}};
  std::cout << fmt::format("held-out observations ({:.1f} %), accuracy in %:\n", 100 * fraction);
  std::string header;
  for (int level = 1; level <= map.label_tree().levels(); ++level) {
    header += fmt::format(" {:>6}", fmt::format("L{}", level));
  }
  std::cout << fmt::format("  {:<16}{:>9}  {} | {:>6}\n", "decoding", "samples", header, "point");
  PrintEvaluation("argmax", evaluations[0].second);
  PrintEvaluation("visibility mask", evaluations[1].second);
  // The yardstick: each point's mean training descriptor, among the points the image sees.
  PrintEvaluation("class means", evaluations[2].second);
  return evaluations;
}

// The output layers `output` names (shared, node, pooled, shortcut), or the map's default
// `defaults` when empty; node rows keep an explicit --node-output-dim.
void ChooseOutputLayers(const std::string& output, const NetworkOptions& defaults,
                        int descriptor_dim, bool node_output_dim_given, NetworkOptions& network) {
  network.descriptor_shortcut = false;
  if (output.empty()) {
    network.pooled_point_rows = defaults.pooled_point_rows && network.node_output_dim > 0;
    network.descriptor_shortcut =
        defaults.descriptor_shortcut && network.node_output_dim == descriptor_dim;
  } else if (output == "shared") {
    network.node_output_dim = 0;
    network.pooled_point_rows = false;
  } else if (output == "shortcut") {
    if (node_output_dim_given && network.node_output_dim != descriptor_dim) {
      ThrowInvalidArgument(
          "--output shortcut scores points at the descriptor's width: --node-output-dim {} is not "
          "the map's descriptor dimension {}",
          network.node_output_dim, descriptor_dim);
    }
    network.node_output_dim = descriptor_dim;
    network.pooled_point_rows = true;
    network.descriptor_shortcut = true;
  } else {
    // A small map's default rows are the shortcut's, at the descriptor's width.
    if (!node_output_dim_given && (network.node_output_dim == 0 || defaults.descriptor_shortcut)) {
      network.node_output_dim =
          DefaultNetworkOptions(kMinPointsForNodeOutputRows, descriptor_dim).node_output_dim;
    }
    network.pooled_point_rows = output == "pooled";
  }
  network.node_conditioning = DefaultNodeConditioning(network);
}

int RunTrain(TrainArguments& arguments) {
  TrainerOptions& options = arguments.options;
  options.device = ParseComputeDevice(arguments.device);
  options.augmentation.enabled = !arguments.no_augment;
  options.checkpoint_path = arguments.checkpoint.empty()
                                ? std::filesystem::path(arguments.map_dir + ".checkpoint.pt")
                                : std::filesystem::path(arguments.checkpoint);
  Timer timer;
  const auto map = LocalizationMap::Load(
      arguments.map_dir,
      {.load_observations = true, .load_network = arguments.eval_only, .device = options.device});
  std::cerr << fmt::format("loaded {} ({} observations of {} points) in {}\n", arguments.map_dir,
                           map->scene().NumObservations(), map->scene().NumPoints(),
                           FormatDuration(timer.ElapsedSeconds()));
  SetComputeThreads(options.num_threads);
  if (arguments.paper) {
    // The paper's network and schedule; explicit width flags still apply.
    const NetworkOptions paper = NetworkOptions::PaperFaithful();
    options.network.node_conditioning = paper.node_conditioning;
    options.network.node_output_dim = paper.node_output_dim;
    arguments.visibility_softmax = false;
    options.schedule = LearningRateSchedule::kHalving;
  }
  const int descriptor_dim = static_cast<int>(map->scene().Dimension());
  const NetworkOptions defaults = DefaultNetworkOptions(map->scene().NumPoints(), descriptor_dim);
  if (!arguments.paper && !arguments.node_output_dim_given) {
    options.network.node_output_dim = defaults.node_output_dim;
  }
  // The widths follow the map with its default output layers (those they were measured with).
  if (!arguments.paper && arguments.output.empty()) {
    if (!arguments.channels_given) options.network.channels = defaults.channels;
    if (!arguments.trunk_channels_given) options.network.trunk_channels = defaults.trunk_channels;
  }
  options.network.shared_trunk = arguments.trunk.empty() ? !arguments.paper && defaults.shared_trunk
                                                         : arguments.trunk == "shared";
  if (!arguments.paper) {
    ChooseOutputLayers(arguments.output, defaults, descriptor_dim, arguments.node_output_dim_given,
                       options.network);
  }
  if (!arguments.point_prototypes_given && options.network.pooled_point_rows) {
    options.point_prototypes = DefaultPointPrototypes(options.network);
  }
  if (!arguments.conditioning.empty()) {
    options.network.node_conditioning = arguments.conditioning == "nodes";
  }
  if (arguments.visibility_softmax) options.visibility_softmax = true;
  if (arguments.dense_node_updates) options.sparse_node_updates = false;
  if (arguments.no_keep_best) options.keep_best = false;
  if (arguments.schedule == "halving") options.schedule = LearningRateSchedule::kHalving;
  if (arguments.schedule == "one-cycle") options.schedule = LearningRateSchedule::kOneCycle;
  if (options.max_iterations == 0 && options.max_minutes == 0 && options.epochs == 0) {
    std::cerr << fmt::format("no budget given: {:.1f} epochs of the map's observations\n",
                             DefaultEpochs(map->scene().NumObservations(), options.network));
  }

  if (arguments.eval_only) {
    if (map->network() == nullptr) {
      ThrowInvalidArgument("map bundle {} holds no trained network (run `hscloc train`)",
                           arguments.map_dir);
    }
    const nlohmann::json training = map->metadata()
                                        .value(map_metadata::kNetwork, nlohmann::json::object())
                                        .value(map_metadata::kTraining, nlohmann::json::object());
    EvaluateHeldOut(*map->network(), *map,
                    training.value(map_metadata::kHoldoutFraction, options.holdout_fraction),
                    training.value(map_metadata::kHoldoutSeed, options.holdout_seed));
    return 0;
  }

  options.Check();
  // Ctrl-C stops training after its current step and keeps what it learned.
  options.stop_requested = StopOnFirstSignal();
  const TrainingResult result = TrainNetwork(map->scene(), map->label_tree(), options);
  if (result.interrupted) {
    std::cout << fmt::format(
        "interrupted after {} iterations: the network so far is kept (continue with --resume)\n",
        result.iterations);
  }
  std::cout << fmt::format(
      "trained {} iterations in {} on {} observations ({} held out), {} parameters\n"
      "  final loss {:.4f}, training accuracy per level (teacher-forced):",
      result.iterations, FormatDuration(result.seconds), result.num_training_observations,
      result.num_held_out_observations, result.network.NumParameters(), result.final_loss);
  for (const double accuracy : result.final_level_accuracies) {
    std::cout << fmt::format(" {:.2f}", 100 * accuracy);
  }
  std::cout << " %\n";
  if (result.stopped_early) {
    std::cout << fmt::format(
        "stopped after {} iterations: the held-out checks since iteration {} fell measurably "
        "below it for {:.0f} % of the budget (--patience)\n",
        result.iterations, result.best_iteration, 100 * options.patience);
  }
  if (!result.held_out_checks.empty()) {
    std::cout << "held-out checks (iteration: masked point accuracy):";
    for (const HeldOutCheck& check : result.held_out_checks) {
      std::cout << fmt::format(" {}: {:.1f} %", check.iteration, 100 * check.point_accuracy);
    }
    std::cout << "\n";
  }
  if (result.best_held_out_accuracy >= 0) {
    std::cout << fmt::format(
        "held-out point accuracy (masked, {} checks) {:.2f} % at iteration {}{}; {}\n",
        result.held_out_checks.size(), 100 * result.best_held_out_accuracy, result.best_iteration,
        result.best_iteration < result.iterations ? " (best kept: later checks were worse)" : "",
        result.converged ? "converged (< 5 % gained over the last quarter of the budget)"
                         : "not converged: still improving, a larger budget would help "
                           "(--epochs, --resume)");
  }
  std::vector<std::pair<std::string, NetworkEvaluation>> evaluations;
  if (arguments.eval && result.num_held_out_observations > 0) {
    evaluations =
        EvaluateHeldOut(result.network, *map, options.holdout_fraction, options.holdout_seed);
  }
  // For `--matcher auto`: on a small map, nearest-neighbour matching may be the cheaper path.
  // Queries run on the CPU, so a network trained elsewhere is not timed there.
  std::optional<MatchingCost> matching_cost;
  if (result.network.device() == ComputeDevice::kCpu) {
    matching_cost = MeasureMatchingCost(*map, result.network);
  }
  WriteNetworkToBundle(arguments.map_dir, result, options, evaluations,
                       matching_cost ? matching_cost->AsNetworkNotes() : nlohmann::json::object());
  std::cout << DescribeAutoMatcher(matching_cost, true, true) << "\n";
  std::cout << fmt::format("network written to {} ({}, {})\n", arguments.map_dir,
                           map_blobs::kNetwork, map_blobs::kTrainingLog);
  return 0;
}

}  // namespace

void AddTrainCommand(CLI::App& app, CommandRunner& run) {
  auto arguments = std::make_shared<TrainArguments>();
  TrainerOptions& options = arguments->options;
  CLI::App* command =
      app.add_subcommand("train", "Train the hierarchical classification network of a map");
  command->add_option("--map", arguments->map_dir, "Map bundle (hscloc build-map)")
      ->required()
      ->check(CLI::ExistingDirectory);
  CLI::Option* iterations =
      command->add_option("--iterations", options.max_iterations, "Iteration budget (0: none)")
          ->capture_default_str();
  command->add_option("--minutes", options.max_minutes, "Time budget in minutes (0: none)")
      ->capture_default_str();
  command
      ->add_option("--epochs", options.epochs,
                   "Budget in passes over the training observations (no budget flag at all: "
                   "chosen from the map's size)")
      ->capture_default_str();
  command->add_option("--schedule", arguments->schedule, "one-cycle (default) or halving")
      ->check(CLI::IsMember({"one-cycle", "halving"}));
  command
      ->add_option("--warmup", options.warmup_fraction,
                   "One-cycle: fraction of the budget warming up")
      ->capture_default_str();
  command
      ->add_option("--node-output-dim", options.network.node_output_dim,
                   "Width r of the per-node output rows (0: the paper's shared output layer; "
                   "default from the map's size)")
      ->each([arguments](const std::string&) { arguments->node_output_dim_given = true; });
  command
      ->add_option("--output", arguments->output,
                   "Output layers: shared (the paper's Linear(C, branching) per level), node (a "
                   "row per tree node), pooled (a row per point, pooled over each child's points "
                   "the image sees), shortcut (pooled rows at the descriptor's width, started "
                   "at the points' mean descriptors, the descriptor added to the last layer's "
                   "projection); default from the map's size: shortcut below 10,000 points, pooled "
                   "from there")
      ->check(CLI::IsMember({"shared", "node", "pooled", "shortcut"}));
  command
      ->add_option("--conditioning", arguments->conditioning,
                   "What the generator reads beside the image: labels (the sum of one embedding "
                   "per coarser label, the paper's) or nodes (one embedding per parent node); "
                   "default: labels with pooled output rows, nodes otherwise")
      ->check(CLI::IsMember({"labels", "nodes"}));
  command->add_flag("--visibility-softmax", arguments->visibility_softmax,
                    "Train each level's softmax over the children the image sees only (then "
                    "localize with --masked-decoding)");
  command->add_flag("--dense-node-updates", arguments->dense_node_updates,
                    "Dense Adam over the node output rows instead of lazy row updates");
  command->add_flag("--paper", arguments->paper,
                    "The paper's configuration: label-sum conditioning, shared output layers, "
                    "full softmax, halving schedule");
  command
      ->add_option("--evaluations", options.evaluations,
                   "Held-out checks during training (early stopping; 0: none)")
      ->capture_default_str();
  command->add_flag("--no-keep-best", arguments->no_keep_best,
                    "Return the last network rather than the best held-out one");
  command
      ->add_option("--patience", options.patience,
                   "End training once the best held-out check is this fraction of the budget "
                   "behind and every later check measurably below it (0: spend the budget)")
      ->check(CLI::Range(0.0, 1.0))
      ->capture_default_str();
  command->add_option("--device", arguments->device, "cpu or cuda")
      ->check(CLI::IsMember({"cpu", "cuda"}))
      ->capture_default_str();
  command->add_flag("--resume", options.resume, "Continue from the checkpoint when it exists");
  command->add_option("--checkpoint", arguments->checkpoint,
                      "Checkpoint file (default: MAP.checkpoint.pt beside the bundle)");
  command->add_option("--snapshots", options.snapshot_dir,
                      "Save the network at every held-out check into this folder "
                      "(network-<iteration>.pt), for accuracy against training time");
  command
      ->add_option("--checkpoint-every", options.checkpoint_every_iterations,
                   "Iterations between checkpoints")
      ->capture_default_str();
  command->add_option("--batch-size", options.batch_size, "Observations per batch")
      ->capture_default_str();
  command->add_option("--lr", options.learning_rate, "Adam learning rate (the one-cycle's peak)")
      ->capture_default_str();
  command
      ->add_option(
          "--channels", options.network.channels,
          fmt::format("Width C of each level's conditioned layers (default from the "
                      "map's size: {} below {} points, else {})",
                      kSmallMapChannels, kMinPointsForNodeOutputRows, NetworkOptions().channels))
      ->each([arguments](const std::string&) { arguments->channels_given = true; });
  command
      ->add_option("--trunk-channels", options.network.trunk_channels,
                   fmt::format("Width H of each level's descriptor trunk, run once per keypoint "
                               "(default as --channels)"))
      ->each([arguments](const std::string&) { arguments->trunk_channels_given = true; });
  command
      ->add_option("--trunk", arguments->trunk,
                   fmt::format("shared (one trunk for every level, run once per keypoint) or "
                               "per-level; default from the map's size: shared from {} points",
                               kMinPointsForNodeOutputRows))
      ->check(CLI::IsMember({"shared", "per-level"}));
  command
      ->add_option("--embedding-dim", options.network.embedding_dim,
                   "Width of the image and label embeddings")
      ->capture_default_str();
  command
      ->add_option("--conditioned-layers", options.network.conditioned_layers,
                   "FiLM-conditioned layers per level (1-3)")
      ->capture_default_str();
  command->add_flag("--no-augment", arguments->no_augment, "Train without descriptor noise");
  command
      ->add_option("--noise-norm", options.augmentation.noise_norm,
                   "Norm of the Gaussian noise added to unit descriptors")
      ->capture_default_str();
  command
      ->add_option("--dimension-dropout", options.augmentation.dimension_dropout,
                   "Probability of zeroing a descriptor dimension")
      ->capture_default_str();
  command
      ->add_option("--image-dropout", options.image_dropout,
                   "Probability of training a sample without its image id")
      ->capture_default_str();
  command
      ->add_option("--point-prototypes", options.point_prototypes,
                   fmt::format("Pooled point rows: rows per point at most, each started from "
                               "the point's own training views; with more than one, the final "
                               "pose matches them as nearest neighbours (default from the map: "
                               "{}, a row per view, below {} points; else 1)",
                               kMaxPointPrototypes, kMinPointsForNodeOutputRows))
      ->check(CLI::Range(1, kMaxPointPrototypes))
      ->each([arguments](const std::string&) { arguments->point_prototypes_given = true; });
  command
      ->add_option("--holdout", options.holdout_fraction,
                   "Fraction of observations held out from training")
      ->capture_default_str();
  command->add_option("--seed", options.seed, "Seed of weights, data order and augmentation")
      ->capture_default_str();
  command->add_option("--threads", options.num_threads, "CPU threads (0: all cores)");
  command
      ->add_option("--log-every", options.log_every_iterations, "Iterations per training log line")
      ->capture_default_str();
  command->add_flag("--eval", arguments->eval,
                    "After training, report per-level and point accuracy on the held-out "
                    "observations (plain and visibility-masked decoding)");
  command->add_flag("--eval-only", arguments->eval_only,
                    "Only evaluate the map's trained network on its held-out observations");
  command->callback([&run, arguments, iterations] {
    // A time budget alone replaces the default iteration budget instead of racing it.
    if (arguments->options.max_minutes > 0 && iterations->count() == 0) {
      arguments->options.max_iterations = 0;
    }
    run = [arguments] { return RunTrain(*arguments); };
  });
}

}  // namespace hscloc
