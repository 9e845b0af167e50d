// Little-endian binary reading and writing with checks: a short read throws and names what was
// being read, so a truncated file is an error, never a silent partial result. (COLMAP's binary
// models, hscloc's map blobs.)
#pragma once

#include <algorithm>
#include <cstdint>
#include <istream>
#include <ostream>
#include <string>
#include <string_view>
#include <type_traits>
#include <vector>

#include "util/check.h"

#if !defined(__BYTE_ORDER__) || __BYTE_ORDER__ != __ORDER_LITTLE_ENDIAN__
#error "hscloc's binary formats are read and written on little-endian hosts only"
#endif

namespace hscloc {

// An input stream over bytes it does not own, seekable, without the copy std::istringstream makes
// (a map blob of a gigabyte is read once, not twice). The bytes must outlive the stream.
class MemoryInputStream : public std::istream {
 public:
  explicit MemoryInputStream(std::string_view bytes) : std::istream(nullptr), buffer_(bytes) {
    rdbuf(&buffer_);
  }

 private:
  class Buffer : public std::streambuf {
   public:
    explicit Buffer(std::string_view bytes) {
      char* begin = const_cast<char*>(bytes.data());  // only ever read: no put area
      setg(begin, begin, begin + bytes.size());
    }

   protected:
    pos_type seekoff(off_type offset, std::ios_base::seekdir direction,
                     std::ios_base::openmode which) override {
      if (!(which & std::ios_base::in)) return pos_type(off_type(-1));
      const off_type base = direction == std::ios_base::beg   ? 0
                            : direction == std::ios_base::cur ? gptr() - eback()
                                                              : egptr() - eback();
      const off_type target = base + offset;
      if (target < 0 || target > egptr() - eback()) return pos_type(off_type(-1));
      setg(eback(), eback() + target, egptr());
      return pos_type(target);
    }
    pos_type seekpos(pos_type position, std::ios_base::openmode which) override {
      return seekoff(off_type(position), std::ios_base::beg, which);
    }
  };
  Buffer buffer_;
};

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
