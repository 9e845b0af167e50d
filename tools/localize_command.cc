#include <fmt/format.h>

#include <iostream>
#include <memory>
#include <string>
#include <vector>

#include "localization/localizer.h"
#include "localization/matcher_choice.h"
#include "localization/query_runner.h"
#include "model/network.h"
#include "scene/feature_io.h"
#include "scene/query_io.h"
#include "tools/commands.h"
#include "util/timer.h"

namespace hscloc {
namespace {

namespace fs = std::filesystem;

struct LocalizeArguments {
  std::string map_dir;
  std::vector<std::string> query_lists;
  std::string features;
  std::string global_features;
  std::string matcher = "auto";
  std::string candidate_search = "all";
  std::string final_pose = FinalPoseName(LocalizerOptions().final_pose);
  std::string retrieval = RetrievalModeName(LocalizerOptions().retrieval);
  std::string device = "cpu";
  bool no_visibility_filter = false;
  bool no_image_id = false;
  bool every_keypoint = false;
  bool uniform_sampling = false;
  LocalizerOptions options;
  QueryListRunOptions run;
};

int RunLocalize(LocalizeArguments& arguments) {
  LocalizerOptions& options = arguments.options;
  options.matcher = ParseMatcher(arguments.matcher);
  options.candidate_search = ParseCandidateSearch(arguments.candidate_search);
  options.final_pose = ParseFinalPose(arguments.final_pose);
  options.retrieval = ParseRetrievalMode(arguments.retrieval);
  options.visibility_filter = !arguments.no_visibility_filter;
  options.use_image_id = !arguments.no_image_id;
  options.one_keypoint_per_point = !arguments.every_keypoint;
  options.sample_by_confidence = !arguments.uniform_sampling;
  options.Check();

  std::vector<QueryWithIntrinsics> queries;
  for (const std::string& list : arguments.query_lists) {
    for (QueryWithIntrinsics& query : ReadQueryList(list)) queries.push_back(std::move(query));
  }
  const std::unique_ptr<FeatureReader> features = OpenFeatureReader(arguments.features);
  GlobalDescriptorMap global_descriptors;
  if (!arguments.global_features.empty()) {
    global_descriptors = ReadH5GlobalDescriptors(arguments.global_features);
  }

  const Timer timer;
  const Localizer localizer =
      Localizer::FromBundle(arguments.map_dir, options, ParseComputeDevice(arguments.device));
  std::cerr << fmt::format("loaded {} in {}; {}\n", arguments.map_dir,
                           FormatDuration(timer.ElapsedSeconds()),
                           DescribeMatcher(localizer, options.matcher));
  const QueryListRunSummary summary =
      RunQueryList(localizer, queries, *features,
                   global_descriptors.empty() ? nullptr : &global_descriptors, arguments.run);

  if (arguments.run.resume) {
    std::cout << fmt::format("resuming: {} of {} queries already in {}\n", summary.num_skipped,
                             summary.num_queries, arguments.run.out.string());
  }
  std::cout << fmt::format(
      "localized {} of {} queries ({} failed, listed in {}) in {}, {} threads, matcher {}\n"
      "{}"
      "retrieval {}: {} queries had a round of point votes, {} were localized by it; {} were "
      "localized by the points' mean descriptors\n"
      "submission: {}\n",
      summary.num_localized, summary.num_queries - summary.num_skipped, summary.num_failed,
      summary.failures_path.string(), FormatDuration(summary.seconds), summary.num_threads,
      MatcherName(localizer.ResolvedMatcher(options.matcher)), FormatStageTable(summary.timings),
      RetrievalModeName(localizer.options().retrieval), summary.num_with_votes,
      summary.num_won_by_votes, summary.num_won_by_nearest_points, arguments.run.out.string());
  if (!arguments.run.timings_out.empty()) {
    std::cout << fmt::format("timings per query: {}\n", arguments.run.timings_out.string());
  }
  return 0;
}

}  // namespace

void AddMatcherOption(CLI::App& command, std::string& matcher) {
  command
      .add_option("--matcher", matcher,
                  "hsc (the network), nn (nearest neighbour) or auto (the one `hscloc train` "
                  "timed cheaper on this map; hsc where it timed none)")
      ->check(CLI::IsMember({MatcherName(Matcher::kAuto), MatcherName(Matcher::kNetwork),
                             MatcherName(Matcher::kNearestNeighbor)}))
      ->capture_default_str();
}

void AddLastRoundOptions(CLI::App& command, LocalizerOptions& options) {
  struct CountOption {
    const char* name;
    int* value;
    const char* description;
  };
  const CountOption last_round[] = {
      {"--nearest-point-candidates", &options.nearest_point_candidates,
       "hsc: where no round found a pose, the global ranking's first images matched by nearest "
       "neighbour against their points' mean descriptors, the --top-k with the most matches posed "
       "(needs a map built with point descriptors; 0: never)"},
      {"--nearest-point-widened-candidates", &options.nearest_point_widened_candidates,
       "hsc: where the last round's images give no pose either, the global ranking's next images "
       "are ranked and posed the same way, each pass up to five times as deep as the last, up to "
       "this one (0: no second pass)"},
      {"--nearest-point-shortlist", &options.nearest_point_shortlist,
       "hsc: the last round counts its images' matches on a sample of the query's keypoints, then "
       "on all of them for this many with the most (0: every image on every keypoint)"},
  };
  for (const CountOption& option : last_round) {
    command.add_option(option.name, *option.value, option.description)
        ->check(CLI::NonNegativeNumber)
        ->capture_default_str();
  }
}

void AddLocalizeCommand(CLI::App& app, CommandRunner& run) {
  auto arguments = std::make_shared<LocalizeArguments>();
  LocalizerOptions& options = arguments->options;
  CLI::App* command = app.add_subcommand(
      "localize", "Localize a list of queries offline and write a submission file");
  command->add_option("--map", arguments->map_dir, "Map bundle (hscloc build-map, hscloc train)")
      ->required()
      ->check(CLI::ExistingDirectory);
  command
      ->add_option("--queries", arguments->query_lists,
                   "Query list(s): NAME MODEL WIDTH HEIGHT PARAMS... per line")
      ->required()
      ->check(CLI::ExistingFile);
  command->add_option("--features", arguments->features, "Query features: .h5 or database.db")
      ->required()
      ->check(CLI::ExistingFile);
  command
      ->add_option("--global-features", arguments->global_features,
                   "Query global descriptors (.h5), for maps built with external ones")
      ->check(CLI::ExistingFile);
  command->add_option("--out", arguments->run.out, "Submission file: NAME QW QX QY QZ TX TY TZ")
      ->required();
  command->add_option(
      "--timings", arguments->run.timings_out,
      "CSV of every query's stage timings in milliseconds, rounds, inliers and RANSAC samples");
  AddMatcherOption(*command, arguments->matcher);
  command->add_option("--top-k", options.top_k, "Retrieved database images")->capture_default_str();
  command
      ->add_option("--retrieval", arguments->retrieval,
                   "global: the global descriptor (VLAD) alone (the paper); global-then-votes: "
                   "when its candidates yield no pose with --vote-below-inliers, the network's "
                   "votes for the images observing its predicted points add --top-k more, "
                   "and where those are weak too the global ranking's next "
                   "--deeper-global-candidates; votes: the votes alone")
      ->check(CLI::IsMember({"global", "global-then-votes", "votes"}))
      ->capture_default_str();
  command
      ->add_option("--vote-below-inliers", options.vote_retrieval_below_inliers,
                   "global-then-votes: inliers of the best candidate below which the votes' round "
                   "runs")
      ->capture_default_str();
  command
      ->add_option("--deeper-global-candidates", options.deeper_global_candidates,
                   "global-then-votes: the global ranking's next images, not yet tried, posed "
                   "where the votes' round is weak too, unless no round has a pose and the last "
                   "round ranks them (0: none)")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  AddLastRoundOptions(*command, options);
  command
      ->add_option("--max-matched-keypoints", options.max_matched_keypoints,
                   "Keypoints matched at most, evenly spaced in the query's order; retrieval's "
                   "global descriptor still pools them all (0: every keypoint)")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  command->add_flag("--exact-votes", options.exact_votes,
                    "Score every point of the map in the votes' pass, also on a map large enough "
                    "for the point row index");
  command->add_flag("--no-visibility-filter", arguments->no_visibility_filter,
                    "Keep matches to points the retrieved image does not see");
  command->add_flag("--every-keypoint", arguments->every_keypoint,
                    "Keep every keypoint the network sends to a point (the paper), not only the "
                    "most confident");
  command->add_flag("--no-image-id", arguments->no_image_id,
                    "Run the network without the retrieved image's id");
  command->add_flag("--masked-decoding", options.visibility_masked_decoding,
                    "Let the network choose only subtrees the retrieved image sees");
  command
      ->add_option("--candidate-search", arguments->candidate_search,
                   "all: pose every retrieved image (the paper); until-accepted: stop at the "
                   "first with --accept-candidate-inliers")
      ->check(CLI::IsMember({"all", "until-accepted"}))
      ->capture_default_str();
  command
      ->add_option("--accept-candidate-inliers", options.accept_candidate_inliers,
                   "Inliers that accept a candidate with --candidate-search until-accepted")
      ->capture_default_str();
  command
      ->add_option("--first-look-samples", options.first_look_samples,
                   "RANSAC samples a candidate draws before every retrieval round is done; the "
                   "rest of its budget follows only while it could still win (0: all at once)")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  command
      ->add_option("--final-pose", arguments->final_pose,
                   "pooled: the matches of every candidate that agrees with the winner's pose, "
                   "posed together; winner: the winning candidate's own pose (the paper)")
      ->check(CLI::IsMember({"winner", "pooled"}))
      ->capture_default_str();
  command
      ->add_option("--threshold", options.pose.max_reprojection_error_px,
                   "RANSAC inlier threshold in pixels")
      ->capture_default_str();
  command
      ->add_option("--ransac-samples", options.pose.max_iterations,
                   "Most RANSAC samples (hypotheses) per retrieved image")
      ->check(CLI::PositiveNumber)
      ->capture_default_str();
  command->add_flag("--uniform-sampling", arguments->uniform_sampling,
                    "RANSAC samples the network's matches uniformly, not the most confident first "
                    "(PROSAC), and every round's candidates draw the whole budget");
  command
      ->add_option("--ransac-seed", options.pose.seed,
                   "Seed of RANSAC's sampling (equal queries and seeds give equal poses)")
      ->capture_default_str();
  command->add_option("--device", arguments->device, "cpu or cuda")
      ->check(CLI::IsMember({"cpu", "cuda"}))
      ->capture_default_str();
  command->add_option("--threads", arguments->run.num_threads,
                      "Queries in parallel (0: all cores)");
  command->add_flag("--resume", arguments->run.resume,
                    "Keep the queries already in --out and localize the rest");
  command->callback([&run, arguments] { run = [arguments] { return RunLocalize(*arguments); }; });
}

}  // namespace hscloc
