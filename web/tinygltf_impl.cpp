// tinygltf_impl.cpp — tinygltf's implementation for the WebAssembly build
// (the native build links Debian's libtinygltf; its header is the same
// Debian file). Images are never decoded (gltf_import.cpp sets its own
// image loader that skips them), so stb_image is compiled but unused.
#define TINYGLTF_IMPLEMENTATION
#define STB_IMAGE_IMPLEMENTATION
#define STB_IMAGE_WRITE_IMPLEMENTATION
#include <tiny_gltf.h>
