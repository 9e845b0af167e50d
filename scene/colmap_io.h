// Reading and writing COLMAP models (cameras, images, points3D) in the binary and text formats of
// COLMAP 3.8 (its src/base/reconstruction.cc).
//
// Binary (little-endian; every list preceded by its length as uint64):
//   cameras.bin   camera_id u32, model_id i32, width u64, height u64, params f64[model's count]
//   images.bin    image_id u32, qvec f64[4] (w, x, y, z), tvec f64[3], camera_id u32,
//                 name (NUL-terminated), points2D[] as (x f64, y f64, point3D_id u64; -1 = none)
//   points3D.bin  point3D_id u64, xyz f64[3], rgb u8[3], error f64,
//                 track[] as (image_id u32, point2D_idx u32)
// Text: one record per line ('#' starts a comment line); images take two lines, the second one
// holding "X Y POINT3D_ID" per 2D point (-1 = none), empty for an image without 2D points.
// Image names cannot contain whitespace in the text format.
//
// Readers never return a partial result: truncated data, a count larger than the rest of the
// stream can hold, bytes after the last declared record, unknown camera models, wrong parameter
// counts, non-numeric fields, duplicate ids and, in text, a record count other than the one a
// COLMAP header comment declares ("# Number of images: 4, ...") all throw std::invalid_argument
// naming `source` (the file) and the record. Quaternions are normalized on reading unless already
// unit to within rounding, as COLMAP normalizes them; a quaternion already unit is kept bit for bit
// so that writing and reading again is the identity.
#pragma once

#include <Eigen/Geometry>
#include <filesystem>
#include <istream>
#include <map>
#include <ostream>
#include <string>

#include "scene/reconstruction.h"

namespace hscloc {

enum class ColmapFormat { kBinary, kText };

// Stream overloads. `source` names the stream in error messages ("map/images.bin"). Each camera
// read is Check()ed; cross-file consistency is Reconstruction::Check()'s job.
std::map<camera_t, Camera> ReadCamerasBinary(std::istream& stream, const std::string& source);
std::map<image_t, Image> ReadImagesBinary(std::istream& stream, const std::string& source);
std::map<point3D_t, Point3D> ReadPoints3DBinary(std::istream& stream, const std::string& source);
std::map<camera_t, Camera> ReadCamerasText(std::istream& stream, const std::string& source);
std::map<image_t, Image> ReadImagesText(std::istream& stream, const std::string& source);
std::map<point3D_t, Point3D> ReadPoints3DText(std::istream& stream, const std::string& source);

// Writers. Text writes every double with 17 significant digits, so reading it back is exact.
// WriteImagesText throws std::invalid_argument for a name that is empty or holds whitespace,
// WriteImagesBinary for one that holds a NUL, before writing anything.
void WriteCamerasBinary(std::ostream& stream, const std::map<camera_t, Camera>& cameras);
void WriteImagesBinary(std::ostream& stream, const std::map<image_t, Image>& images);
void WritePoints3DBinary(std::ostream& stream, const std::map<point3D_t, Point3D>& points3D);
void WriteCamerasText(std::ostream& stream, const std::map<camera_t, Camera>& cameras);
void WriteImagesText(std::ostream& stream, const std::map<image_t, Image>& images);
void WritePoints3DText(std::ostream& stream, const std::map<point3D_t, Point3D>& points3D);

// kBinary when `dir` holds cameras.bin, images.bin and points3D.bin (preferred, as COLMAP does),
// else kText when it holds the three .txt files; otherwise throws naming the missing files.
ColmapFormat DetectColmapFormat(const std::filesystem::path& dir);

// Reads the model in `dir` (format detected) and Check()s it; errors name the file, or the
// directory for an inconsistency between files.
Reconstruction ReadColmapModel(const std::filesystem::path& dir);

// Writes the three files into `dir` (created if missing), replacing existing ones. Throws
// std::invalid_argument naming the file that could not be written; files written before it
// stay.
void WriteColmapModel(const Reconstruction& reconstruction, const std::filesystem::path& dir,
                      ColmapFormat format);

namespace internal {

// Shared by the binary and the text readers, not meant for other callers.

// cam_from_world rotation from COLMAP's (w, x, y, z); throws naming `record` for a zero or
// non-finite quaternion.
Eigen::Quaterniond QuaternionFromColmap(double w, double x, double y, double z,
                                        const std::string& record);
// camera.Check(), its message prefixed with `source`.
void CheckCameraFrom(const Camera& camera, const std::string& source);

}  // namespace internal

}  // namespace hscloc
