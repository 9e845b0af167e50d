// Binary serialization of a Scene for map bundles: the geometry (cameras, database images, point
// ids and positions) and, apart, the observations with their descriptors (float16, half the
// size; SIFT's integer values and unit SuperPoint-like descriptors both survive to 3 digits).
// The geometry is what serving needs; observations are for training and explicit matching.
#pragma once

#include <cstdint>
#include <iosfwd>
#include <string>
#include <vector>

#include "scene/scene.h"

namespace hscloc {

void WriteSceneGeometry(std::ostream& stream, const Scene& scene);
// Fills cameras, images, point ids and positions (no observations). Throws naming `source` when
// the data is truncated or inconsistent.
Scene ReadSceneGeometry(std::istream& stream, const std::string& source);

void WriteSceneObservations(std::ostream& stream, const Scene& scene);

// Writes what WriteSceneObservations writes for a scene of indices only (Scene::FromReconstruction
// of ObservationIndices) from descriptor rows appended in observation order, so that a map's
// descriptors are never held at once. Finish() throws unless exactly every row came.
class SceneObservationsWriter {
 public:
  SceneObservationsWriter(std::ostream& stream, const Scene& scene, int64_t dimension);
  void Append(const DescriptorMatrix& rows);
  void Finish() const;

 private:
  std::ostream& stream_;
  uint64_t expected_rows_;
  int64_t dimension_;
  uint64_t rows_ = 0;
  std::vector<uint16_t> halves_;
};
// Adds the observations to a scene read by ReadSceneGeometry; throws naming `source` when an
// index is out of range or the data is truncated.
void ReadSceneObservations(std::istream& stream, const std::string& source, Scene& scene);

}  // namespace hscloc
