// image.h — RGBA8 images on the CPU: PNG output, text labels, composition.
//
// Rows top to bottom, 4 bytes per pixel. Text is drawn with stb_easy_font
// (a tiny vector font from libstb-dev) rasterised as solid quads, scaled by an
// integer factor; no font file is needed.
#pragma once
#include <cstdint>
#include <string>
#include <vector>

#include <glm/glm.hpp>

namespace progskin::render {

struct Image {
    int width = 0, height = 0;
    std::vector<uint8_t> rgba;  // width * height * 4

    Image() = default;
    Image(int w, int h, glm::u8vec4 fill = {255, 255, 255, 255});
    uint8_t* at(int x, int y) { return rgba.data() + (size_t(y) * size_t(width) + size_t(x)) * 4; }
    const uint8_t* at(int x, int y) const { return rgba.data() + (size_t(y) * size_t(width) + size_t(x)) * 4; }
    bool empty() const { return width <= 0 || height <= 0; }
};

// Writes a PNG (stb_image_write); false when the file cannot be written.
bool write_png(const Image& img, const std::string& path);

// Solid rectangle, clipped to the image.
void fill_rect(Image& img, int x, int y, int w, int h, glm::u8vec4 color);
// Copies src into dst with its top-left corner at (x, y), clipped.
void blit(Image& dst, const Image& src, int x, int y);

// Text with stb_easy_font at an integer scale (glyphs are about 6*scale wide,
// 12*scale line height); '\n' starts a new line. Returns the drawn width.
int draw_text(Image& img, int x, int y, const std::string& text, glm::u8vec4 color, int scale = 2);
int text_width(const std::string& text, int scale = 2);
int text_height(const std::string& text, int scale = 2);

// Heat map colour for t in [0,1]: Google's Turbo colormap (polynomial fit) from 0.1 to 1.
glm::vec3 heat_color(float t);

}  // namespace progskin::render
