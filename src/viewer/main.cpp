// The csb-view executable of a C++ build; the Python package's `csb-view` runs the same command.
#include "viewer/command.hpp"

int main(int argc, char** argv) { return csb::viewer::command(argc, argv); }
