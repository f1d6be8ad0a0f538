# Injected with -DCMAKE_PROJECT_INCLUDE by xrce.agent.interfaces so that an unmodified interface
# package builds against ROS 2 installed from PyPI wheels. Runs right after the package's project().
#
# Inputs (set on the cmake command line by the Python driver):
#   XRCE_PYTHON_INCLUDE_DIR  this interpreter's Python.h directory
#   XRCE_NUMPY_INCLUDE_DIR   numpy's C headers of this interpreter
#   XRCE_C_ONLY              ON: generate only what rclpy loads (C typesupports + Python bindings)

# 1. The message wheels export their <pkg>__rosidl_generator_py targets with include directories of
#    the machine that built the wheels (/opt/python/cp311-cp311/...). CMake refuses to generate with
#    include directories that do not exist, so once every find_package() has run, point those entries
#    at this machine's Python and numpy headers.
function(_xrce_fix_wheel_include_dirs)
  get_property(_targets DIRECTORY "${CMAKE_SOURCE_DIR}" PROPERTY IMPORTED_TARGETS)
  foreach(_target IN LISTS _targets)
    get_target_property(_dirs ${_target} INTERFACE_INCLUDE_DIRECTORIES)
    if(NOT _dirs)
      continue()
    endif()
    set(_fixed "")
    set(_changed FALSE)
    foreach(_dir IN LISTS _dirs)
      if(_dir MATCHES "^/opt/python/cp[0-9]+-cp[0-9]+/")
        set(_changed TRUE)
        if(_dir MATCHES "numpy")
          list(APPEND _fixed "${XRCE_NUMPY_INCLUDE_DIR}")
        else()
          list(APPEND _fixed "${XRCE_PYTHON_INCLUDE_DIR}")
        endif()
      else()
        list(APPEND _fixed "${_dir}")
      endif()
    endforeach()
    if(_changed)
      list(REMOVE_DUPLICATES _fixed)
      set_target_properties(${_target} PROPERTIES INTERFACE_INCLUDE_DIRECTORIES "${_fixed}")
    endif()
  endforeach()
endfunction()
cmake_language(DEFER DIRECTORY "${CMAKE_SOURCE_DIR}" CALL _xrce_fix_wheel_include_dirs)

# 2. rclpy only loads the C type supports; the C++ generators roughly double build time and size.
#    Load ament_cmake_core now (its config is include-once) so that the override below is the one
#    rosidl_generate_interfaces() sees, and skip the C++ generators when extensions run.
if(XRCE_C_ONLY)
  find_package(ament_cmake_core REQUIRED)
  macro(ament_execute_extensions extension_point)
    if("${extension_point}" STREQUAL "rosidl_generate_idl_interfaces")
      _ament_execute_extensions(${extension_point} ${ARGN} EXCLUDE
        rosidl_generator_cpp
        rosidl_typesupport_cpp
        rosidl_typesupport_fastrtps_cpp
        rosidl_typesupport_introspection_cpp)
    else()
      _ament_execute_extensions(${extension_point} ${ARGN})
    endif()
  endmacro()
endif()
