# Lets a colcon/CMake build find ROS 2 packages installed from the `ros-*` wheels on PyPI
# (a virtual environment used as the ament prefix, clients/ros2/tools/colcon_build.sh).
#
# Those wheels are built in a manylinux container, and the CMake exports of their
# Python type support (`<pkg>::<pkg>__rosidl_generator_py`, e.g. std_msgs's) still name
# that container's Python headers (/opt/python/cp311-cp311/include/python3.11 and its
# numpy) as include directories. CMake refuses to generate a build that uses an imported
# target naming a folder that does not exist. This file, given as
# -DCMAKE_PROJECT_INCLUDE, drops such folders from every imported target's
# INTERFACE_INCLUDE_DIRECTORIES once the package's CMakeLists.txt has been read (the
# package's own Python type support takes this Python's headers and numpy from
# find_package(Python3 ... Development NumPy) as usual). Nothing else is changed, and
# a build against a ROS 2 distribution's own packages never needs it.
function(_vamos_drop_missing_include_dirs)
  get_property(targets DIRECTORY "${CMAKE_SOURCE_DIR}" PROPERTY IMPORTED_TARGETS)
  foreach(target IN LISTS targets)
    get_target_property(dirs ${target} INTERFACE_INCLUDE_DIRECTORIES)
    if(NOT dirs)
      continue()
    endif()
    set(kept "")
    set(dropped "")
    foreach(dir IN LISTS dirs)
      # Generator expressions are evaluated later: kept as they are.
      if(dir MATCHES "^\\$<" OR EXISTS "${dir}")
        list(APPEND kept "${dir}")
      else()
        list(APPEND dropped "${dir}")
      endif()
    endforeach()
    if(dropped)
      message(STATUS "wheel prefix: ${target}: dropped missing include folders ${dropped}")
      set_target_properties(${target} PROPERTIES INTERFACE_INCLUDE_DIRECTORIES "${kept}")
    endif()
  endforeach()
endfunction()
cmake_language(DEFER DIRECTORY "${CMAKE_SOURCE_DIR}" CALL _vamos_drop_missing_include_dirs)
