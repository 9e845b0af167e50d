// Reading and writing COLMAP models (cameras, images, points3D) in binary and text formats.
#pragma once
#include "model/reconstruction.h"
