#include "image.h"

#include <algorithm>

// The one translation unit with the stb implementations. Static linkage, so
// they never clash with copies inside other libraries (tinygltf, libstb).
#define STB_IMAGE_WRITE_IMPLEMENTATION
#define STB_IMAGE_WRITE_STATIC
#if defined(__GNUC__)
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wmissing-field-initializers"
#pragma GCC diagnostic ignored "-Wunused-function"
#pragma GCC diagnostic ignored "-Wsign-compare"
#endif
#include <stb_easy_font.h>
#include <stb_image_write.h>
#if defined(__GNUC__)
#pragma GCC diagnostic pop
#endif

namespace progskin::render {

Image::Image(int w, int h, glm::u8vec4 fill) : width(w), height(h), rgba(size_t(w) * size_t(h) * 4) {
    for (size_t i = 0; i < rgba.size(); i += 4) {
        rgba[i] = fill.r;
        rgba[i + 1] = fill.g;
        rgba[i + 2] = fill.b;
        rgba[i + 3] = fill.a;
    }
}

bool write_png(const Image& img, const std::string& path) {
    if (img.empty()) return false;
    return stbi_write_png(path.c_str(), img.width, img.height, 4, img.rgba.data(), img.width * 4) != 0;
}

void fill_rect(Image& img, int x, int y, int w, int h, glm::u8vec4 c) {
    const int x0 = std::max(0, x), y0 = std::max(0, y);
    const int x1 = std::min(img.width, x + w), y1 = std::min(img.height, y + h);
    for (int yy = y0; yy < y1; ++yy)
        for (int xx = x0; xx < x1; ++xx) {
            uint8_t* p = img.at(xx, yy);
            const float a = c.a / 255.0f;
            for (int k = 0; k < 3; ++k) p[k] = uint8_t(p[k] + (float(c[k]) - p[k]) * a + 0.5f);
            p[3] = 255;
        }
}

void blit(Image& dst, const Image& src, int x, int y) {
    for (int yy = 0; yy < src.height; ++yy) {
        const int ty = y + yy;
        if (ty < 0 || ty >= dst.height) continue;
        for (int xx = 0; xx < src.width; ++xx) {
            const int tx = x + xx;
            if (tx < 0 || tx >= dst.width) continue;
            std::copy_n(src.at(xx, yy), 4, dst.at(tx, ty));
        }
    }
}

int draw_text(Image& img, int x, int y, const std::string& text, glm::u8vec4 color, int scale) {
    // stb_easy_font emits quads (4 vertices of 16 bytes: x, y, z floats + colour).
    static char buffer[99999];
    std::string t = text;
    const int quads = stb_easy_font_print(0, 0, t.data(), nullptr, buffer, sizeof buffer);
    const float* v = reinterpret_cast<const float*>(buffer);
    for (int q = 0; q < quads; ++q) {
        const float* a = v + q * 16;  // 4 vertices * 4 floats
        const float qx0 = std::min(a[0], a[8]), qx1 = std::max(a[0], a[8]);
        const float qy0 = std::min(a[1], a[9]), qy1 = std::max(a[1], a[9]);
        fill_rect(img, x + int(qx0 * scale), y + int(qy0 * scale), int((qx1 - qx0) * scale), int((qy1 - qy0) * scale),
                  color);
    }
    return text_width(text, scale);
}

int text_width(const std::string& text, int scale) {
    std::string t = text;
    return stb_easy_font_width(t.data()) * scale;
}

int text_height(const std::string& text, int scale) {
    std::string t = text;
    return stb_easy_font_height(t.data()) * scale;
}

glm::vec3 heat_color(float t) {
    t = 0.1f + 0.9f * std::clamp(t, 0.0f, 1.0f);  // skip Turbo's near-black start: zero error stays readable
    const glm::vec4 kr(0.13572138f, 4.61539260f, -42.66032258f, 132.13108234f);
    const glm::vec4 kg(0.09140261f, 2.19418839f, 4.84296658f, -14.18503333f);
    const glm::vec4 kb(0.10667330f, 12.64194608f, -60.58204836f, 110.36276771f);
    const glm::vec2 kr2(-152.94239396f, 59.28637943f), kg2(4.27729857f, 2.82956604f), kb2(-89.90310912f, 27.34824973f);
    const glm::vec4 v4(1.0f, t, t * t, t * t * t);
    const glm::vec2 v2 = glm::vec2(v4.z, v4.w) * v4.z;
    return glm::clamp(glm::vec3(glm::dot(v4, kr) + glm::dot(v2, kr2), glm::dot(v4, kg) + glm::dot(v2, kg2),
                                glm::dot(v4, kb) + glm::dot(v2, kb2)),
                      0.0f, 1.0f);
}

}  // namespace progskin::render
