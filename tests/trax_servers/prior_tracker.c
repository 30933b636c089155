/* A TraX tracker written in C, for tests/test_trax.py: proof that a tracker in another language,
 * linked against libtrax, runs as mata-eval's block A.
 *
 * It answers each frame with a box of the initial size centred on MATA's search centre (the
 * frame properties prior_x, prior_y; its previous box when they are absent) and reports as
 * `confidence` the mean of the frame's bytes / 255, read from the 24-bit BMP file whose path it
 * receives (it declares only the `path` image format).
 *
 * The vot-trax wheel ships libtrax.so but no header, so the few functions used are declared here
 * from trax.h (TraX 4, https://github.com/votchallenge/trax/blob/master/include/trax.h).
 * Build: cc prior_tracker.c -o prior_tracker -L<trax package dir> -l:libtrax.so -Wl,-rpath,<dir>
 */
#include <stdio.h>
#include <stdlib.h>

typedef struct trax_handle trax_handle;
typedef struct trax_metadata trax_metadata;
typedef struct trax_image trax_image;
typedef struct trax_image_list trax_image_list;
typedef struct trax_properties trax_properties;
typedef struct trax_object_list trax_object_list;
typedef void trax_region;
typedef void (*trax_logger)(const char *string, int length, void *obj);
typedef struct { int flags; trax_logger callback; void *data; } trax_logging;

enum { TRAX_ERROR = -1, TRAX_INITIALIZE = 2, TRAX_FRAME = 3, TRAX_QUIT = 4 };
enum { TRAX_IMAGE_PATH = 1, TRAX_REGION_RECTANGLE = 2, TRAX_CHANNEL_COLOR = 1 };

trax_logging trax_logger_setup(trax_logger callback, void *data, int flags);
trax_metadata *trax_metadata_create(int region_formats, int image_formats, int channels,
                                    const char *name, const char *description, const char *family, int flags);
void trax_metadata_release(trax_metadata **metadata);
trax_handle *trax_server_setup_v(trax_metadata *metadata, trax_logging log, int verbosity);
int trax_server_wait_mot(trax_handle *server, trax_image_list **images, trax_object_list **objects,
                         trax_properties *properties);
int trax_server_reply_mot(trax_handle *server, trax_object_list *objects);
trax_object_list *trax_object_list_create(int size);
void trax_object_list_release(trax_object_list **list);
void trax_object_list_set(trax_object_list *list, int index, trax_region *region);
trax_region *trax_object_list_get(trax_object_list *list, int index);
trax_properties *trax_object_list_properties(trax_object_list *list, int index);
int trax_cleanup(trax_handle **handle);
trax_image *trax_image_list_get(const trax_image_list *list, int channel);
void trax_image_list_release(trax_image_list **list);
const char *trax_image_get_path(const trax_image *image);
trax_region *trax_region_create_rectangle(float x, float y, float width, float height);
void trax_region_get_rectangle(const trax_region *region, float *x, float *y, float *width, float *height);
void trax_region_release(trax_region **region);
trax_properties *trax_properties_create(void);
void trax_properties_clear(trax_properties *properties);
void trax_properties_release(trax_properties **properties);
int trax_properties_has(const trax_properties *properties, const char *key);
float trax_properties_get_float(const trax_properties *properties, const char *key, float def);
void trax_properties_set_float(trax_properties *properties, const char *key, float value);

/* Mean of the pixel bytes of an uncompressed 24-bit BMP (rows padded to 4 bytes), -1 on error. */
static double bmp_mean(const char *path) {
    FILE *f = fopen(path, "rb");
    unsigned char header[54];
    if (!f || fread(header, 1, 54, f) != 54 || header[0] != 'B' || header[1] != 'M' || header[28] != 24) {
        if (f) fclose(f);
        return -1.0;
    }
    long offset = header[10] | header[11] << 8 | header[12] << 16 | (long)header[13] << 24;
    long width = header[18] | header[19] << 8 | header[20] << 16 | (long)header[21] << 24;
    long height = labs((long)(int)(header[22] | header[23] << 8 | header[24] << 16 | (unsigned)header[25] << 24));
    long row = (3 * width + 3) / 4 * 4;
    unsigned char *data = malloc(row);
    double sum = 0.0;
    fseek(f, offset, SEEK_SET);
    for (long y = 0; y < height; y++) {
        if (fread(data, 1, row, f) != (size_t)row) { sum = -1.0; break; }
        for (long i = 0; i < 3 * width; i++) sum += data[i];
    }
    free(data);
    fclose(f);
    return sum < 0 ? -1.0 : sum / (3.0 * width * height);
}

int main(void) {
    trax_metadata *meta = trax_metadata_create(TRAX_REGION_RECTANGLE, TRAX_IMAGE_PATH, TRAX_CHANNEL_COLOR,
                                               "prior_tracker", "C test tracker", "", 0);
    trax_handle *server = trax_server_setup_v(meta, trax_logger_setup(NULL, NULL, 0), 0);
    trax_metadata_release(&meta);
    trax_properties *props = trax_properties_create();
    float x = 0, y = 0, w = 0, h = 0;
    for (;;) {
        trax_image_list *images = NULL;
        trax_object_list *objects = NULL;
        trax_properties_clear(props);
        /* the object-list calls, as the vot-trax client speaks them (the _sot ones refuse) */
        int status = trax_server_wait_mot(server, &images, &objects, props);
        if (status != TRAX_INITIALIZE && status != TRAX_FRAME) break;
        double mean = bmp_mean(trax_image_get_path(trax_image_list_get(images, TRAX_CHANNEL_COLOR)));
        trax_image_list_release(&images);
        if (mean < 0) {
            fprintf(stderr, "prior_tracker: cannot read the frame as a 24-bit BMP\n");
            return 2;
        }
        if (status == TRAX_INITIALIZE) {
            trax_region_get_rectangle(trax_object_list_get(objects, 0), &x, &y, &w, &h);
        } else if (trax_properties_has(props, "prior_x") && trax_properties_has(props, "prior_y")) {
            x = trax_properties_get_float(props, "prior_x", 0) - w / 2;
            y = trax_properties_get_float(props, "prior_y", 0) - h / 2;
        }
        if (objects) trax_object_list_release(&objects);
        trax_object_list *answer = trax_object_list_create(1);
        trax_region *box = trax_region_create_rectangle(x, y, w, h);
        trax_object_list_set(answer, 0, box);
        trax_region_release(&box);
        trax_properties_set_float(trax_object_list_properties(answer, 0), "confidence", (float)(mean / 255.0));
        trax_server_reply_mot(server, answer);
        trax_object_list_release(&answer);
    }
    trax_properties_release(&props);
    trax_cleanup(&server);
    return 0;
}
