// Each subcommand of `hscloc` registers its options and, when chosen, sets the function to run.
#pragma once

#include <CLI/CLI.hpp>
#include <functional>
#include <string>

namespace hscloc {

using CommandRunner = std::function<int()>;

struct LocalizerOptions;

void AddSynthCommand(CLI::App& app, CommandRunner& run);
void AddExtractCommand(CLI::App& app, CommandRunner& run);
void AddTriangulateCommand(CLI::App& app, CommandRunner& run);
void AddBankCommand(CLI::App& app, CommandRunner& run);
void AddBuildMapCommand(CLI::App& app, CommandRunner& run);
void AddInspectCommand(CLI::App& app, CommandRunner& run);
void AddTrainCommand(CLI::App& app, CommandRunner& run);
void AddLocalizeCommand(CLI::App& app, CommandRunner& run);
void AddEvalCommand(CLI::App& app, CommandRunner& run);
void AddPipelineCommand(CLI::App& app, CommandRunner& run);
void AddServeCommand(CLI::App& app, CommandRunner& run);
void AddKeygenCommand(CLI::App& app, CommandRunner& run);
void AddDemoCommand(CLI::App& app, CommandRunner& run);

// The options of the localizer's last round (nearest_point_*), for every command that localizes.
void AddLastRoundOptions(CLI::App& command, LocalizerOptions& options);
// --matcher (auto, hsc or nn), for every command that localizes with a trained map.
void AddMatcherOption(CLI::App& command, std::string& matcher);

}  // namespace hscloc
