#include "model/reconstruction.h"
#include <gtest/gtest.h>
