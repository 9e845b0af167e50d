// The synthetic city's random streams (internal to synthetic/): each part of the city draws from
// its own stream, keyed further by an index, so that adding a draw to one part moves no other.
#pragma once

#include <cstdint>

namespace hscloc {

enum SyntheticStream : uint64_t {
  kStreamHeights = 1,
  kStreamFacadePoints,
  kStreamGroundPoints,
  kStreamRepeated,
  kStreamDevices,
  kStreamDatabaseViews,
  kStreamQueries,
  kStreamPointDescriptor,
  kStreamViewFeatures,
  kStreamBankTracks,
  kStreamBankReuse,
};

}  // namespace hscloc
