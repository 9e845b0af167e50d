// The matches of several retrieved images pooled into one set for a final pose. The paper solves
// one pose per retrieved image from the matches to the points that image sees; a query that sees
// a street head-on shares few points with any one database image, and one image's points can
// leave the pose free to slide along the viewing direction. Pooling the matches of the images
// whose matches agree with the winning pose gives the final pose the points of all of them, as
// hloc pools a query's matches over its retrieved images and COLMAP's registrator over every
// overlapping image.
#pragma once

#include <vector>

#include "localization/nearest_neighbor_matcher.h"

namespace hscloc {

// The union of `parts`: each (keypoint, point) pair once, ordered by keypoint then point. Where
// some parts carry confidences, a pair keeps its highest, a match of a part without them
// counting at 0 (nearest-neighbour matches pooled with the network's); where none does, the union
// has none. Throws std::invalid_argument when a part's confidences are neither one per match nor
// none.
CandidateMatches UniteMatches(const std::vector<const CandidateMatches*>& parts);

}  // namespace hscloc
