# Every external dependency of hscloc, found once, as imported targets (Debian 12 packages;
# scripts/install-deps.sh installs them).

find_package(Threads REQUIRED)
find_package(Eigen3 3.3 REQUIRED NO_MODULE)
find_package(OpenCV 4 REQUIRED COMPONENTS core imgproc calib3d features2d imgcodecs dnn)
# Debian's Ceres links ATLAS's libf77blas and libatlas by name, in its own target and through the
# BLAS that its SuiteSparse search finds. As direct dependencies of every executable they come
# first in the symbol lookup and serve each sgemm_ of the process, libtorch's too: a 2048^3
# product ran at 34 GFLOPS instead of OpenBLAS's 147 on 2 cores. The generic libblas.so.3, which
# Debian's alternatives point at OpenBLAS, provides the same symbols.
set(BLA_VENDOR Generic)
find_package(Ceres REQUIRED)
get_target_property(_ceres_link_libraries Ceres::ceres INTERFACE_LINK_LIBRARIES)
list(FILTER _ceres_link_libraries EXCLUDE REGEX "libf77blas|libatlas")
set_target_properties(Ceres::ceres PROPERTIES INTERFACE_LINK_LIBRARIES "${_ceres_link_libraries}")
# FAISS's config expects OpenMP to be found first.
find_package(OpenMP REQUIRED)
find_package(faiss REQUIRED)
find_package(Torch REQUIRED)
find_package(cppzmq REQUIRED)
find_package(prometheus-cpp REQUIRED)
find_package(Protobuf REQUIRED)
find_package(HDF5 REQUIRED COMPONENTS C CXX)
find_package(SQLite3 REQUIRED)
find_package(OpenSSL REQUIRED COMPONENTS Crypto)
find_package(CLI11 REQUIRED)
find_package(fmt REQUIRED)
find_package(spdlog REQUIRED)
find_package(nlohmann_json 3 REQUIRED)
find_package(GTest REQUIRED)
find_package(benchmark REQUIRED)
# The Python client's tests need the interpreter that Debian's python3-zmq, python3-protobuf,
# python3-numpy, python3-h5py and python3-pytest serve: the first of the python3 on the PATH and
# /usr/bin/python3 that imports them (HSCLOC_PYTHON chooses another).
find_package(Python3 COMPONENTS Interpreter)
set(HSCLOC_PYTHON "" CACHE FILEPATH "Python 3 for the Python client's tests (empty: found)")
set(HSCLOC_PYTHON_EXECUTABLE "${HSCLOC_PYTHON}")
if(NOT HSCLOC_PYTHON_EXECUTABLE)
  foreach(_python ${Python3_EXECUTABLE} /usr/bin/python3)
    execute_process(COMMAND ${_python} -c "import zmq, google.protobuf, numpy, h5py, pytest"
      RESULT_VARIABLE _python_missing OUTPUT_QUIET ERROR_QUIET)
    if(_python_missing EQUAL 0)
      set(HSCLOC_PYTHON_EXECUTABLE ${_python})
      break()
    endif()
  endforeach()
endif()
if(NOT HSCLOC_PYTHON_EXECUTABLE)
  message(WARNING "No python3 imports zmq, google.protobuf, numpy, h5py and pytest: the Python "
                  "client's tests will fail (scripts/install-deps.sh installs them)")
  set(HSCLOC_PYTHON_EXECUTABLE python3)
endif()
find_program(COLMAP_EXECUTABLE colmap DOC "The COLMAP binary; tests cross-check our models with it")
find_program(PROMTOOL_EXECUTABLE promtool DOC "Prometheus's promtool; tests check the metrics with it")

# libtorch's config gives a variable list; keep its flags on the one target that needs them.
if(NOT TARGET hscloc::torch)
  add_library(hscloc::torch INTERFACE IMPORTED)
  target_link_libraries(hscloc::torch INTERFACE ${TORCH_LIBRARIES})
  target_include_directories(hscloc::torch INTERFACE ${TORCH_INCLUDE_DIRS})
endif()
