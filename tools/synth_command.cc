#include <fmt/format.h>
#include <fmt/ranges.h>
#include <sys/resource.h>

#include <iostream>
#include <memory>

#include "synthetic/synthetic_city.h"
#include "synthetic/synthetic_city_writer.h"
#include "tools/commands.h"
#include "util/timer.h"

namespace hscloc {
namespace {

struct SynthArguments {
  std::string preset = "small";
  std::string output_dir;
  uint64_t seed = 0;
  int descriptor_dim = 0;
  int num_day_queries = -1;
  int num_night_queries = -1;
  double repeated_fraction = -1;
  std::string appearance = "random";
  std::string bank;
  double bank_reuse_noise = -1;
  double bank_view_noise = -1;
  int num_threads = 0;
  bool overwrite = false;
  bool float32 = false;
};

double PeakMemoryMiB() {
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  return usage.ru_maxrss / 1024.0;  // Linux reports KiB
}

int RunSynth(const SynthArguments& arguments) {
  SyntheticCityOptions options = SyntheticCityOptions::Preset(arguments.preset);
  options.seed = arguments.seed;
  if (arguments.descriptor_dim > 0) options.descriptor_dim = arguments.descriptor_dim;
  if (arguments.num_day_queries >= 0) options.num_day_queries = arguments.num_day_queries;
  if (arguments.num_night_queries >= 0) options.num_night_queries = arguments.num_night_queries;
  if (arguments.repeated_fraction >= 0) options.repeated_fraction = arguments.repeated_fraction;
  if (arguments.bank_reuse_noise >= 0) options.bank_reuse_noise = arguments.bank_reuse_noise;
  if (arguments.bank_view_noise >= 0) options.bank_view_noise = arguments.bank_view_noise;
  std::shared_ptr<const DescriptorBank> bank;
  if (arguments.appearance == "real") {
    if (arguments.bank.empty()) {
      std::cerr << "error: --appearance real needs --bank (made by `hscloc bank`)\n";
      return 1;
    }
    if (arguments.descriptor_dim > 0) {
      std::cerr << "error: --descriptor-dim is the bank's with --appearance real\n";
      return 1;
    }
    bank = std::make_shared<const DescriptorBank>(DescriptorBank::Load(arguments.bank));
    std::cerr << fmt::format("bank {}: {} tracks, {} views of {}-D {} descriptors from {}\n",
                             arguments.bank, bank->NumTracks(), bank->NumViews(), bank->dimension(),
                             bank->feature(), fmt::join(bank->sources(), ", "));
  } else if (!arguments.bank.empty()) {
    std::cerr << "error: --bank is for --appearance real\n";
    return 1;
  }

  Timer timer;
  const SyntheticCity city(options, bank);
  std::cerr << fmt::format("laid out {} blocks, {} points, {} database views in {}\n",
                           city.blocks().size(), city.points().size(), city.database_views().size(),
                           FormatDuration(timer.ElapsedSeconds()));
  SyntheticCityWriteOptions write_options;
  write_options.num_threads = arguments.num_threads;
  write_options.overwrite = arguments.overwrite;
  write_options.precision =
      arguments.float32 ? H5FloatPrecision::kFloat32 : H5FloatPrecision::kFloat16;
  const SyntheticCityStats stats = WriteSyntheticCity(city, arguments.output_dir, write_options);

  std::cout << fmt::format(
      "synthetic city '{}' (seed {}) written to {}\n"
      "  database images   {:>10}\n"
      "  map points        {:>10}  (of {} city points)\n"
      "  observations      {:>10}  (mean track length {:.2f})\n"
      "  database keypoints{:>10}\n"
      "  queries           {:>10}  day, {} night\n"
      "  descriptor dim    {:>10}\n"
      "  time              {:>10}\n"
      "  peak memory       {:>10.0f}  MiB\n",
      arguments.preset, options.seed, arguments.output_dir, stats.num_database_images,
      stats.num_map_points, stats.num_city_points, stats.num_database_observations,
      stats.mean_track_length, stats.num_database_keypoints, stats.num_day_queries,
      stats.num_night_queries, city.options().descriptor_dim,
      FormatDuration(timer.ElapsedSeconds()), PeakMemoryMiB());
  return 0;
}

}  // namespace

void AddSynthCommand(CLI::App& app, CommandRunner& run) {
  auto arguments = std::make_shared<SynthArguments>();
  CLI::App* command = app.add_subcommand("synth", "Generate a synthetic city with ground truth");
  command->add_option("--preset", arguments->preset, "tiny, small, city or aachen")
      ->check(CLI::IsMember(SyntheticCityOptions::PresetNames()))
      ->capture_default_str();
  command->add_option("--out", arguments->output_dir, "Output directory")->required();
  command->add_option("--seed", arguments->seed, "Random seed")->capture_default_str();
  command->add_option("--descriptor-dim", arguments->descriptor_dim,
                      "Descriptor dimension (default: the preset's)");
  command->add_option("--day-queries", arguments->num_day_queries,
                      "Number of day queries (default: the preset's)");
  command->add_option("--night-queries", arguments->num_night_queries,
                      "Number of night queries (default: the preset's)");
  command->add_option("--repeated-fraction", arguments->repeated_fraction,
                      "Share of points that copy another building's appearance");
  command
      ->add_option("--appearance", arguments->appearance,
                   "random (a random unit vector per point plus noise) or real (descriptors of "
                   "real photos from --bank)")
      ->check(CLI::IsMember({"random", "real"}))
      ->capture_default_str();
  command->add_option("--bank", arguments->bank, "Descriptor bank (hscloc bank)")
      ->check(CLI::ExistingFile);
  command->add_option("--bank-view-noise", arguments->bank_view_noise,
                      "Norm of the noise each view adds to its bank descriptor (default: the "
                      "preset's)");
  command->add_option("--bank-reuse-noise", arguments->bank_reuse_noise,
                      "Norm of the noise that sets a bank track's later uses apart (default: "
                      "the preset's)");
  command->add_option("--threads", arguments->num_threads, "Threads (0: all cores)");
  command->add_flag("--overwrite", arguments->overwrite, "Replace an existing output directory");
  command->add_flag("--float32", arguments->float32,
                    "Store descriptors as float32 (default float16, as hloc)");
  command->callback([&run, arguments] { run = [arguments] { return RunSynth(*arguments); }; });
}

}  // namespace hscloc
