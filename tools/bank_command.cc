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
  std::vector<DescriptorBank> banks;
  for (size_t i = 0; i < arguments.sets.size(); ++i) {
    const std::string& set = arguments.sets[i];
    const Timer timer;
    const std::filesystem::path set_dir(set);
    std::cerr << fmt::format("{}: {} of the photos and of their night versions\n", set,
                             arguments.feature);
    // Numbered: two sets may share a folder name.
    const std::string name = std::filesystem::absolute(set_dir).lexically_normal().filename();
    banks.push_back(
        BankFromSet(set_dir, work / fmt::format("{}-{}", i + 1, name), arguments.options));
    const DescriptorBank& bank = banks.back();
    std::cout << fmt::format(
        "{}: {} tracks, {} views ({:.2f} per track), {:.1f} % found again at night, {}\n", set,
        bank.NumTracks(), bank.NumViews(),
        static_cast<double>(bank.NumViews()) / std::max<size_t>(1, bank.NumTracks()),
        100.0 * static_cast<double>(bank.NumNightViews()) / std::max<size_t>(1, bank.NumViews()),
        FormatDuration(timer.ElapsedSeconds()));
  }
  const DescriptorBank bank = DescriptorBank::Concatenate(banks);
  if (bank.NumTracks() == 0) {
    std::cerr << "error: the sets hold no track of two or more views\n";
    return 1;
  }
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
