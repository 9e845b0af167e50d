#include <fmt/format.h>

#include <fstream>
#include <iostream>
#include <memory>
#include <string>
#include <unordered_set>
#include <vector>

#include "localization/pose_evaluation.h"
#include "report/error_curves.h"
#include "scene/query_io.h"
#include "tools/commands.h"
#include "util/check.h"

namespace hscloc {
namespace {

struct EvalArguments {
  std::string ground_truth;
  std::string results;
  std::string conditions;
  std::string plot;
  std::string title;
  bool per_query = false;
};

int RunEval(const EvalArguments& arguments) {
  const std::vector<NamedPose> ground_truth = ReadPoses(arguments.ground_truth);
  const std::vector<NamedPose> results = ReadPoses(arguments.results);
  const std::vector<QueryPoseError> errors = ComputePoseErrors(ground_truth, results);
  std::vector<ConditionAccuracy> accuracies;
  if (arguments.conditions.empty()) {
    accuracies.push_back(SummarizeAccuracy("all", errors, AachenThresholds()));
  } else {
    accuracies = SummarizeAccuracyByCondition(errors, ParseConditions(arguments.conditions),
                                              AachenThresholds());
  }
  size_t missing = 0;
  for (const QueryPoseError& error : errors) missing += !error.estimated;
  if (arguments.per_query) {
    for (const QueryPoseError& error : errors) {
      std::cout << fmt::format("{:<40} {:>12.4f} m {:>10.3f} deg{}\n", error.name, error.position,
                               error.rotation_deg, error.estimated ? "" : "  (no result)");
    }
  }
  std::cout << FormatAccuracyTable(accuracies);
  if (missing > 0) {
    std::cout << fmt::format("{} of {} ground-truth queries have no result (counted as failures)\n",
                             missing, errors.size());
  }
  if (!arguments.plot.empty()) {
    std::ofstream plot(arguments.plot);
    plot << CumulativeErrorSvg(accuracies,
                               arguments.title.empty() ? arguments.results : arguments.title);
    if (!plot) ThrowInvalidArgument("cannot write {}", arguments.plot);
    std::cout << fmt::format("cumulative error plot: {}\n", arguments.plot);
  }
  return 0;
}

}  // namespace

void AddEvalCommand(CLI::App& app, CommandRunner& run) {
  auto arguments = std::make_shared<EvalArguments>();
  CLI::App* command =
      app.add_subcommand("eval", "Evaluate a submission against ground-truth poses");
  command->add_option("--gt", arguments->ground_truth, "Ground truth: NAME QW QX QY QZ TX TY TZ")
      ->required()
      ->check(CLI::ExistingFile);
  command->add_option("--results", arguments->results, "Submission file (hscloc localize)")
      ->required()
      ->check(CLI::ExistingFile);
  command->add_option("--conditions", arguments->conditions,
                      "Conditions reported apart: NAME:QUERY_LIST,... (e.g. day:day.txt,night:"
                      "night.txt); default: all queries together");
  command->add_option("--plot", arguments->plot,
                      "Write the cumulative error plot (SVG) here (default: RESULTS.svg)");
  command->add_option("--title", arguments->title, "Title of the plot");
  command->add_flag("--per-query", arguments->per_query, "Also list every query's errors");
  command->callback([&run, arguments] {
    if (arguments->plot.empty()) arguments->plot = arguments->results + ".svg";
    run = [arguments] { return RunEval(*arguments); };
  });
}

}  // namespace hscloc
