#include <fmt/format.h>

#include <algorithm>
#include <iostream>
#include <memory>
#include <numeric>

#include "localization/localization_map.h"
#include "map/map_bundle.h"
#include "tools/commands.h"

namespace hscloc {
namespace {

int RunInspect(const std::string& bundle_dir) {
  const MapBundle bundle = MapBundle::Open(bundle_dir);
  std::cout << fmt::format("map bundle {} (format version {}, checksums verified)\n", bundle_dir,
                           bundle.manifest().value("format_version", 0));
  std::cout << "files:\n";
  uint64_t total_bytes = 0;
  for (const std::string& name : bundle.BlobNames()) {
    total_bytes += bundle.BlobSize(name);
    std::cout << fmt::format("  {:<24}{:>12.2f} MiB\n", name, bundle.BlobSize(name) / 1048576.0);
  }
  std::cout << fmt::format("  {:<24}{:>12.2f} MiB\n", "total", total_bytes / 1048576.0);
  std::cout << "metadata:\n" << bundle.metadata().dump(2) << "\n";

  const auto map = LocalizationMap::Load(bundle_dir);
  const LabelTree& tree = map->label_tree();
  std::vector<size_t> nodes_per_level(tree.levels() + 1, 0);
  for (uint32_t node = 0; node < tree.NumNodes(); ++node) nodes_per_level[tree.NodeLevel(node)]++;
  std::cout << "label tree nodes per level:";
  for (const size_t count : nodes_per_level) std::cout << ' ' << count;
  std::cout << '\n';

  const Visibility& visibility = map->visibility();
  std::vector<size_t> per_image(visibility.NumImages());
  for (uint32_t i = 0; i < per_image.size(); ++i) per_image[i] = visibility.NumPointsOfImage(i);
  if (!per_image.empty()) {
    const auto [min, max] = std::minmax_element(per_image.begin(), per_image.end());
    std::cout << fmt::format(
        "points seen per database image: min {}, mean {:.1f}, max {}\n", *min,
        std::accumulate(per_image.begin(), per_image.end(), 0.0) / per_image.size(), *max);
  }
  std::cout << fmt::format("retrieval: {} images indexed, dimension {}, {}\n",
                           map->global_index().size(), map->global_index().dimension(),
                           map->vlad() ? "VLAD from local features" : "external descriptors");
  return 0;
}

}  // namespace

void AddInspectCommand(CLI::App& app, CommandRunner& run) {
  auto bundle_dir = std::make_shared<std::string>();
  CLI::App* command = app.add_subcommand("inspect", "Print a map bundle's manifest and statistics");
  command->add_option("map", *bundle_dir, "Map bundle directory")->required();
  command->callback([&run, bundle_dir] { run = [bundle_dir] { return RunInspect(*bundle_dir); }; });
}

}  // namespace hscloc
