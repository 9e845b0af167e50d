#include <fmt/format.h>

#include <iostream>
#include <memory>

#include "bank/bank_builder.h"
#include "tools/commands.h"
#include "util/timer.h"

namespace hscloc {
namespace {

struct BankArguments {
  std::vector<std::string> sets;
  std::string feature = "xfeat";
  std::string out;
  std::string work;  // empty: OUT.work
  BankSetOptions options;
};

int RunBank(BankArguments& arguments) {
  arguments.options.extractor.type = ParseFeatureType(arguments.feature);
  const std::filesystem::path work = arguments.work.empty()
                                         ? std::filesystem::path(arguments.out + ".work")
                                         : std::filesystem::path(arguments.work);
  std::vector<std::filesystem::path> sets(arguments.sets.begin(), arguments.sets.end());
  const auto report_set = [&](const std::filesystem::path& set, const DescriptorBank& bank,
                              double seconds) {
    std::cout << fmt::format(
        "{}: {} tracks, {} views ({:.2f} per track), {:.1f} % found again at night, {}\n",
        set.string(), bank.NumTracks(), bank.NumViews(),
        static_cast<double>(bank.NumViews()) / std::max<size_t>(1, bank.NumTracks()),
        100.0 * static_cast<double>(bank.NumNightViews()) / std::max<size_t>(1, bank.NumViews()),
        FormatDuration(seconds));
  };
  std::cerr << fmt::format("{} of the photos and of their night versions, set by set\n",
                           arguments.feature);
  const DescriptorBank bank = BankFromSets(sets, work, arguments.options, report_set);
  bank.Save(arguments.out);
  std::cout << fmt::format("bank written to {}: {} tracks, {} views of {}-D {} descriptors\n",
                           arguments.out, bank.NumTracks(), bank.NumViews(), bank.dimension(),
                           bank.feature());
  return 0;
}

}  // namespace

void AddBankCommand(CLI::App& app, CommandRunner& run) {
  auto arguments = std::make_shared<BankArguments>();
  BankSetOptions& options = arguments->options;
  CLI::App* command = app.add_subcommand(
      "bank",
      "Make a bank of real descriptors (each SfM track's views, day and night) from real photo "
      "sets, for `hscloc synth --appearance real`");
  command
      ->add_option("--set", arguments->sets,
                   "A real set: a folder with images/ and map/ (a COLMAP model of the photos' "
                   "poses); repeatable")
      ->required()
      ->check(CLI::ExistingDirectory);
  command->add_option("--feature", arguments->feature, "xfeat or sift")
      ->check(CLI::IsMember({"xfeat", "sift"}))
      ->capture_default_str();
  command->add_option("--out", arguments->out, "The bank file")->required();
  command->add_option("--work", arguments->work,
                      "Folder of the features, maps and night photos made on the way (default: "
                      "OUT.work; an interrupted run resumes there)");
  command->add_option("--xfeat-model", options.extractor.xfeat.model_path, "XFeat ONNX model")
      ->capture_default_str();
  command
      ->add_option("--night-match-px", options.night_match_px,
                   "Farthest a night keypoint may lie from its day keypoint")
      ->check(CLI::PositiveNumber)
      ->capture_default_str();
  command
      ->add_option("--colmap", options.triangulation.colmap.colmap_executable,
                   "The COLMAP 3.8 executable")
      ->capture_default_str();
  command->callback([&run, arguments] { run = [arguments] { return RunBank(*arguments); }; });
}

}  // namespace hscloc
