package nail2nail;

import com.machinezoo.sourceafis.FingerprintImage;
import com.machinezoo.sourceafis.FingerprintImageOptions;
import com.machinezoo.sourceafis.FingerprintMatcher;
import com.machinezoo.sourceafis.FingerprintTemplate;
import java.awt.color.ColorSpace;
import java.awt.image.BufferedImage;
import java.awt.image.Raster;
import java.io.BufferedReader;
import java.io.ByteArrayInputStream;
import java.io.IOException;
import java.io.InputStreamReader;
import java.io.PrintStream;
import java.nio.charset.StandardCharsets;
import java.nio.file.Files;
import java.nio.file.Path;
import java.util.HashMap;
import java.util.Map;
import javax.imageio.ImageIO;

/**
 * Score fingerprint image pairs with SourceAFIS.
 *
 * <p>Usage: {@code java -jar nail2nail-matcher.jar [--dpi 500] [--imageio-grey] < pairs.tsv}
 *
 * <p>Each stdin line is {@code PROBE_PATH<TAB>CANDIDATE_PATH} (PNG, JPEG, BMP, ... as decoded by
 * SourceAFIS; 8-bit grayscale expected); blank lines are skipped. One score per line is printed
 * to stdout, in input order. Templates are extracted once per path and matchers built once per
 * probe path, so an N x M matrix costs N + M extractions. Any bad line or unreadable image ends
 * the run with exit status 1 and a message on stderr naming the line.
 *
 * <p>8-bit greyscale images (with or without alpha) are read as their samples say: sample v is
 * the grey level v, as SourceAFIS's own raw-pixel constructor takes it. SourceAFIS's decoder
 * reads files through {@code ImageIO} and {@code BufferedImage.getRGB}, which treats an 8-bit
 * grey PNG as linear light (the JDK's {@code CS_GRAY}) and converts it to sRGB: every grey level
 * but 0 and 255 comes out brighter (128 reads as 188), while the same picture stored as RGB or
 * with a palette is read unchanged. {@code --imageio-grey} scores grey files that way, as
 * earlier versions of this harness did. Other images go to SourceAFIS's decoder.
 */
public final class Match {
    private static final String USAGE =
        "usage: java -jar nail2nail-matcher.jar [--dpi DPI] [--imageio-grey] < pairs.tsv\n"
            + "  stdin: one 'PROBE_PATH<TAB>CANDIDATE_PATH' per line; stdout: one score per line";

    private final double dpi;
    private final boolean imageioGrey;
    private final Map<String, FingerprintTemplate> templates = new HashMap<>();
    private final Map<String, FingerprintMatcher> matchers = new HashMap<>();

    private Match(double dpi, boolean imageioGrey) {
        this.dpi = dpi;
        this.imageioGrey = imageioGrey;
    }

    /** The samples of an 8-bit grey image (band 0; alpha ignored), or null for other images. */
    private static byte[] greySamples(BufferedImage image) {
        if (image == null) {
            return null;
        }
        Raster raster = image.getRaster();
        boolean grey = image.getColorModel().getColorSpace().getType() == ColorSpace.TYPE_GRAY;
        if (!grey || raster.getSampleModel().getSampleSize(0) != 8) {
            return null;
        }
        int w = image.getWidth();
        int h = image.getHeight();
        int[] samples = raster.getSamples(0, 0, w, h, 0, (int[]) null);
        byte[] pixels = new byte[w * h];
        for (int i = 0; i < pixels.length; i++) {
            pixels[i] = (byte) samples[i];
        }
        return pixels;
    }

    private FingerprintImage image(byte[] bytes) throws IOException {
        FingerprintImageOptions options = new FingerprintImageOptions().dpi(dpi);
        if (!imageioGrey) {
            BufferedImage decoded = ImageIO.read(new ByteArrayInputStream(bytes));
            byte[] pixels = greySamples(decoded);
            if (pixels != null) {
                return new FingerprintImage(decoded.getWidth(), decoded.getHeight(), pixels,
                    options);
            }
        }
        return new FingerprintImage(bytes, options);
    }

    private FingerprintTemplate template(String path) throws IOException {
        FingerprintTemplate t = templates.get(path);
        if (t == null) {
            byte[] bytes = Files.readAllBytes(Path.of(path));
            t = new FingerprintTemplate(image(bytes));
            templates.put(path, t);
        }
        return t;
    }

    private double score(String probe, String candidate) throws IOException {
        FingerprintMatcher m = matchers.get(probe);
        if (m == null) {
            m = new FingerprintMatcher(template(probe));
            matchers.put(probe, m);
        }
        return m.match(template(candidate));
    }

    private static void fail(String message) {
        System.err.println("nail2nail-matcher: " + message);
        System.exit(1);
    }

    public static void main(String[] args) throws IOException {
        double dpi = 500;
        boolean imageioGrey = false;
        for (int i = 0; i < args.length; i++) {
            switch (args[i]) {
                case "--dpi":
                    if (i + 1 >= args.length) {
                        fail("--dpi: missing value\n" + USAGE);
                    }
                    try {
                        dpi = Double.parseDouble(args[++i]);
                    } catch (NumberFormatException e) {
                        fail("--dpi: expected a number, got '" + args[i] + "'");
                    }
                    if (!(dpi >= 20 && dpi <= 20000)) {
                        fail("--dpi: expected 20..20000, got " + dpi);
                    }
                    break;
                case "--imageio-grey":
                    imageioGrey = true;
                    break;
                case "-h":
                case "--help":
                    System.out.println(USAGE);
                    return;
                default:
                    fail("unknown argument '" + args[i] + "'\n" + USAGE);
            }
        }
        Match match = new Match(dpi, imageioGrey);
        PrintStream out = new PrintStream(System.out, false, StandardCharsets.UTF_8);
        BufferedReader in = new BufferedReader(new InputStreamReader(System.in, StandardCharsets.UTF_8));
        String line;
        int lineNo = 0;
        while ((line = in.readLine()) != null) {
            lineNo++;
            if (line.isBlank()) {
                continue;
            }
            String[] fields = line.split("\t", -1);
            if (fields.length != 2) {
                fail("line " + lineNo + ": expected 'PROBE<TAB>CANDIDATE', got "
                    + fields.length + " field(s)");
            }
            try {
                out.println(match.score(fields[0], fields[1]));
            } catch (IOException | RuntimeException e) {
                fail("line " + lineNo + ": " + e);
            }
        }
        out.flush();
    }
}
