// Little-endian binary reading and writing with checks: a short read throws and names what was
// being read, so a truncated file is an error, never a silent partial result. (COLMAP's binary
// models, hscloc's map blobs.)
#pragma once

#include <algorithm>
#include <cstdint>
#include <istream>
#include <ostream>
#include <string>
#include <type_traits>
#include <vector>

#include "util/check.h"

#if !defined(__BYTE_ORDER__) || __BYTE_ORDER__ != __ORDER_LITTLE_ENDIAN__
#error "hscloc's binary formats are read and written on little-endian hosts only"
#endif

namespace hscloc {

// Reads one value; `what` names the record for the error message ("points3D.bin: point 17 x").
template <typename T>
T ReadBinary(std::istream& stream, const std::string& what) {
  static_assert(std::is_trivially_copyable_v<T>);
  T value;
  stream.read(reinterpret_cast<char*>(&value), sizeof(T));
  if (stream.gcount() != static_cast<std::streamsize>(sizeof(T))) {
    ThrowInvalidArgument("truncated data: {} ({} bytes expected, {} read)", what, sizeof(T),
                         stream.gcount());
  }
  return value;
}

template <typename T>
void ReadBinaryArray(std::istream& stream, T* values, size_t count, const std::string& what) {
  static_assert(std::is_trivially_copyable_v<T>);
  const auto bytes = static_cast<std::streamsize>(count * sizeof(T));
  stream.read(reinterpret_cast<char*>(values), bytes);
  if (stream.gcount() != bytes) {
    ThrowInvalidArgument("truncated data: {} ({} bytes expected, {} read)", what, bytes,
                         stream.gcount());
  }
}

// Reads `count` values into a vector, growing it chunk by chunk: a corrupt count fails at the end
// of the data instead of first allocating whatever the count claims.
template <typename T>
std::vector<T> ReadBinaryVector(std::istream& stream, uint64_t count, const std::string& what) {
  constexpr uint64_t kChunkElements = uint64_t{1} << 20;
  std::vector<T> values;
  for (uint64_t done = 0; done < count;) {
    const uint64_t chunk = std::min(count - done, kChunkElements);
    values.resize(done + chunk);
    ReadBinaryArray(stream, values.data() + done, chunk, what);
    done += chunk;
  }
  return values;
}

// Reads a NUL-terminated string of at most max_length characters.
std::string ReadBinaryCString(std::istream& stream, const std::string& what,
                              size_t max_length = 4096);

template <typename T>
void WriteBinary(std::ostream& stream, const T& value) {
  static_assert(std::is_trivially_copyable_v<T>);
  stream.write(reinterpret_cast<const char*>(&value), sizeof(T));
}

template <typename T>
void WriteBinaryArray(std::ostream& stream, const T* values, size_t count) {
  static_assert(std::is_trivially_copyable_v<T>);
  stream.write(reinterpret_cast<const char*>(values),
               static_cast<std::streamsize>(count * sizeof(T)));
}

}  // namespace hscloc
