//! `index.html`: the report's Markdown as one self-contained page, its figures inlined as SVG and its rollout
//! GIFs embedded, so the file can be mailed or opened anywhere without the folder beside it.
use anyhow::{Context, Result};
use base64::Engine as _;
use pulldown_cmark::{Event, Options, Parser, Tag, TagEnd};
use std::path::Path;

/// The page of `markdown` (the report's `index.md`), whose figures and videos lie in `dir`.
pub fn page(markdown: &str, dir: &Path, title: &str) -> Result<String> {
    let mut events = Vec::new();
    let mut parser = Parser::new_ext(markdown, Options::ENABLE_TABLES);
    while let Some(event) = parser.next() {
        match event {
            // A figure whose SVG lies beside its PNG is inlined as that SVG.
            Event::Start(Tag::Image { dest_url, .. }) if dest_url.ends_with(".png") => {
                let svg = dir.join(format!("{}.svg", dest_url.trim_end_matches(".png")));
                skip_to(&mut parser, TagEnd::Image);
                let figure = match std::fs::read_to_string(&svg) {
                    Ok(text) => format!("<figure>{}</figure>", without_xml_declaration(&text)),
                    Err(_) => format!("<img src=\"{dest_url}\">"),
                };
                events.push(Event::Html(figure.into()));
            }
            // A link to a recorded rollout becomes the GIF itself.
            Event::Start(Tag::Link { dest_url, .. }) if dest_url.ends_with(".gif") => {
                let path = dir.join(dest_url.as_ref());
                let bytes = std::fs::read(&path).with_context(|| format!("reading {}", path.display()))?;
                skip_to(&mut parser, TagEnd::Link);
                let data = base64::engine::general_purpose::STANDARD.encode(bytes);
                events.push(Event::Html(format!("<img class=\"video\" src=\"data:image/gif;base64,{data}\">").into()));
            }
            e => events.push(e),
        }
    }
    let mut body = String::new();
    pulldown_cmark::html::push_html(&mut body, events.into_iter());
    Ok(format!(
        "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n<title>{}</title>\n<style>{STYLE}</style>\n\
         </head>\n<body>\n{body}</body>\n</html>\n",
        escape(title)
    ))
}

/// Consumes events up to and including the end of the current `end` tag.
fn skip_to(parser: &mut Parser, end: TagEnd) {
    for e in parser.by_ref() {
        if e == Event::End(end) {
            break;
        }
    }
}

fn without_xml_declaration(svg: &str) -> &str {
    match svg.find("<svg") {
        Some(at) => &svg[at..],
        None => svg,
    }
}

fn escape(s: &str) -> String {
    s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;")
}

/// Readable tables and figures; GIFs at the policy's frame size are enlarged without smoothing.
const STYLE: &str = "body{font-family:sans-serif;max-width:1100px;margin:2em auto;padding:0 1em;color:#222}\
table{border-collapse:collapse;margin:1em 0}th,td{border:1px solid #ccc;padding:.3em .6em;text-align:left}\
th{background:#f3f3f3}code{background:#f6f6f6;padding:0 .2em}figure{margin:1em 0}figure svg{max-width:100%;height:auto}\
img.video{width:480px;image-rendering:pixelated}";

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn figures_are_inlined_and_videos_embedded() {
        let dir = std::env::temp_dir().join(format!("oneshot-html-{}", std::process::id()));
        std::fs::create_dir_all(dir.join("videos")).unwrap();
        std::fs::write(dir.join("fig.svg"), "<?xml version=\"1.0\"?>\n<svg id=\"fig\"></svg>").unwrap();
        std::fs::write(dir.join("videos/a.gif"), b"GIF89a").unwrap();
        let md = "# T <1>\n\n| a | b |\n| --- | --- |\n| 1 | [episode 0](videos/a.gif) |\n\n![a figure](fig.png)\n\n\
                  [CSV](table1.csv)\n";
        let html = page(md, &dir, "T <1>").unwrap();
        assert!(html.contains("<table>") && html.contains("<td>1</td>"), "{html}");
        assert!(html.contains("<figure><svg id=\"fig\"></svg></figure>") && !html.contains("<?xml"), "{html}");
        assert!(html.contains("src=\"data:image/gif;base64,R0lGODlh\""), "{html}");
        assert!(!html.contains("episode 0") && !html.contains("a figure"), "link and alt texts are replaced");
        assert!(html.contains("<a href=\"table1.csv\">CSV</a>") && html.contains("<title>T &lt;1&gt;</title>"));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
