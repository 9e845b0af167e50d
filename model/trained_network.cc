// A trained network after training: its accuracy on observations (each conditioned on its own
// image), and its place in the map bundle (model/trainer.h).
#include <algorithm>
#include <limits>
#include <nlohmann/json.hpp>
#include <vector>

#include "map/map_blobs.h"
#include "map/map_bundle.h"
#include "model/trainer.h"
#include "util/check.h"
#include "util/timer.h"

namespace hscloc {

namespace {

// Counts into `correct[j]` whether the predicted label path equals the true one up to level j.
void CountLabelPrefix(const LabelTree::Label* predicted, const LabelTree::Label* truth, int levels,
                      std::vector<size_t>& correct) {
  for (int level = 0; level < levels && predicted[level] == truth[level]; ++level) {
    ++correct[level];
  }
}

}  // namespace

NetworkEvaluation EvaluateNetwork(const Network& network, const Scene& scene, const LabelTree& tree,
                                  const std::vector<uint32_t>& observation_indices,
                                  const Visibility* visibility_mask) {
  Timer timer;
  const int levels = tree.levels();
  std::vector<std::vector<uint32_t>> by_image(scene.NumImages());
  for (const uint32_t observation : observation_indices) {
    THROW_CHECK_LT(size_t{observation}, scene.NumObservations());
    by_image[scene.observation_image_indices[observation]].push_back(observation);
  }
  NetworkEvaluation evaluation;
  evaluation.num_observations = observation_indices.size();
  std::vector<size_t> correct_levels(levels, 0);
  size_t correct_points = 0;
  for (uint32_t image = 0; image < by_image.size(); ++image) {
    const std::vector<uint32_t>& observations = by_image[image];
    if (observations.empty()) continue;
    DescriptorMatrix descriptors(observations.size(), scene.Dimension());
    for (size_t i = 0; i < observations.size(); ++i) {
      descriptors.row(i) = scene.observation_descriptors.row(observations[i]);
    }
    const PointPredictions predictions =
        network.Predict(descriptors, {image}, tree, visibility_mask);
    for (size_t i = 0; i < observations.size(); ++i) {
      const uint32_t point = scene.observation_point_indices[observations[i]];
      CountLabelPrefix(&predictions.labels(i, 0), tree.LabelsOfPoint(point), levels,
                       correct_levels);
      if (predictions.point_indices(0, i) == point) ++correct_points;
    }
  }
  const double count = std::max<double>(1, evaluation.num_observations);
  for (const size_t correct : correct_levels)
    evaluation.level_accuracies.push_back(correct / count);
  evaluation.leaf_accuracy = correct_points / count;
  evaluation.seconds = timer.ElapsedSeconds();
  return evaluation;
}

NetworkEvaluation EvaluateNearestClassMean(const Scene& scene, const LabelTree& tree,
                                           const Visibility& visibility,
                                           const std::vector<uint32_t>& evaluated) {
  Timer timer;
  THROW_CHECK_MSG(visibility.NumImages() == scene.NumImages(),
                  "EvaluateNearestClassMean: visibility of {} images for a scene of {}",
                  visibility.NumImages(), scene.NumImages());
  std::vector<char> is_evaluated(scene.NumObservations(), 0);
  for (const uint32_t observation : evaluated) {
    THROW_CHECK_LT(size_t{observation}, scene.NumObservations());
    is_evaluated[observation] = 1;
  }
  Eigen::MatrixXf means = Eigen::MatrixXf::Zero(scene.NumPoints(), scene.Dimension());
  for (size_t observation = 0; observation < scene.NumObservations(); ++observation) {
    if (is_evaluated[observation]) continue;
    const auto descriptor = scene.observation_descriptors.row(observation);
    const float norm = descriptor.norm();
    if (norm > 0) means.row(scene.observation_point_indices[observation]) += descriptor / norm;
  }
  for (int64_t point = 0; point < means.rows(); ++point) {
    const float norm = means.row(point).norm();
    if (norm > 0) means.row(point) /= norm;
  }
  NetworkEvaluation evaluation;
  evaluation.num_observations = evaluated.size();
  std::vector<size_t> correct_levels(tree.levels(), 0);
  size_t correct_points = 0;
  for (const uint32_t observation : evaluated) {
    const uint32_t image = scene.observation_image_indices[observation];
    const auto descriptor = scene.observation_descriptors.row(observation);
    float best_score = -std::numeric_limits<float>::infinity();
    int64_t best_point = -1;
    for (const uint32_t* point = visibility.PointsBegin(image);
         point != visibility.PointsEnd(image); ++point) {
      if (means.row(*point).squaredNorm() == 0) continue;
      const float score = means.row(*point).dot(descriptor);
      if (score > best_score) {
        best_score = score;
        best_point = *point;
      }
    }
    if (best_point < 0) continue;
    const uint32_t truth = scene.observation_point_indices[observation];
    CountLabelPrefix(tree.LabelsOfPoint(static_cast<uint32_t>(best_point)),
                     tree.LabelsOfPoint(truth), tree.levels(), correct_levels);
    correct_points += best_point == truth;
  }
  const double count = std::max<double>(1, evaluation.num_observations);
  for (const size_t correct : correct_levels) {
    evaluation.level_accuracies.push_back(correct / count);
  }
  evaluation.leaf_accuracy = correct_points / count;
  evaluation.seconds = timer.ElapsedSeconds();
  return evaluation;
}

void WriteNetworkToBundle(const std::filesystem::path& bundle_dir, const TrainingResult& result,
                          const TrainerOptions& options,
                          const std::vector<std::pair<std::string, NetworkEvaluation>>& evaluations,
                          const nlohmann::json& notes) {
  MapBundleWriter writer = MapBundleWriter::Update(bundle_dir);
  writer.AddBlob(map_blobs::kNetwork, [&](std::ostream& stream) { result.network.Save(stream); });
  const std::string csv = result.LogCsv();
  writer.AddBlob(map_blobs::kTrainingLog,
                 [&](std::ostream& stream) { stream.write(csv.data(), csv.size()); });

  const NetworkShape& shape = result.network.shape();
  const NetworkOptions& network_options = result.network.options();
  nlohmann::json json;
  json["shape"] = {{"descriptor_dim", shape.descriptor_dim},
                   {"levels", shape.levels},
                   {"branching", shape.branching},
                   {"num_images", shape.num_images},
                   {"point_rows", shape.NumPointRows()}};
  json["options"] = {{"channels", network_options.channels},
                     {"trunk_channels", network_options.trunk_channels},
                     {"embedding_dim", network_options.embedding_dim},
                     {"conditioned_layers", network_options.conditioned_layers},
                     {"node_conditioning", network_options.node_conditioning},
                     {"node_output_dim", network_options.node_output_dim},
                     {"pooled_point_rows", network_options.pooled_point_rows},
                     {"descriptor_shortcut", network_options.descriptor_shortcut},
                     {"masked_decoding", network_options.masked_decoding},
                     {"shared_trunk", network_options.shared_trunk}};
  json["parameters"] = result.network.NumParameters();
  json["training"] = {
      {"iterations", result.iterations},
      {"seconds", result.seconds},
      {"final_loss", result.final_loss},
      {"final_level_accuracies", result.final_level_accuracies},
      {"batch_size", options.batch_size},
      {"learning_rate", options.learning_rate},
      {"halving_fractions", options.halving_fractions},
      {"schedule", options.schedule == LearningRateSchedule::kOneCycle ? "one_cycle" : "halving"},
      {"visibility_softmax", options.visibility_softmax},
      {"best_iteration", result.best_iteration},
      {"best_held_out_accuracy", result.best_held_out_accuracy},
      {"converged", result.converged},
      {"augmentation",
       {{"enabled", options.augmentation.enabled},
        {"noise_norm", options.augmentation.noise_norm},
        {"dimension_dropout", options.augmentation.dimension_dropout}}},
      {"image_dropout", options.image_dropout},
      {"seed", options.seed},
      {"holdout_fraction", options.holdout_fraction},
      {"holdout_seed", options.holdout_seed},
      {"training_observations", result.num_training_observations},
      {"held_out_observations", result.num_held_out_observations},
      {"device", ComputeDeviceName(options.device)}};
  // The time-to-accuracy curve of this training (hscloc-bench draws it per map size).
  nlohmann::json checks = nlohmann::json::array();
  for (const HeldOutCheck& check : result.held_out_checks) {
    checks.push_back({{"iteration", check.iteration},
                      {"seconds", check.seconds},
                      {"point_accuracy", check.point_accuracy}});
  }
  json["training"]["held_out_checks"] = checks;
  nlohmann::json evaluation_json = nlohmann::json::object();
  for (const auto& [name, evaluation] : evaluations) {
    evaluation_json[name] = {{"observations", evaluation.num_observations},
                             {"level_accuracies", evaluation.level_accuracies},
                             {"leaf_accuracy", evaluation.leaf_accuracy}};
  }
  json["evaluations"] = evaluation_json;
  for (const auto& [key, value] : notes.items()) json[key] = value;
  writer.metadata()[map_metadata::kNetwork] = json;
  writer.Commit();
}

}  // namespace hscloc
