#include "geometry/rigid3d.h"
#include <gtest/gtest.h>
