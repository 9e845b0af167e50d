#include "geometry/camera.h"
#include <gtest/gtest.h>
