//! The web page at `/ui`: HTML, CSS and JavaScript modules compiled into the binary (no
//! network beyond the gateway, no build step), served with a strict Content-Security-Policy:
//! scripts and styles only from these files, no inline script or style, no `eval`, DOM
//! string sinks refused (Trusted Types), connections only back to the gateway. The page
//! itself holds no data (so its routes name no operation and need no token); it reads
//! the REST API and its event stream with the visitor's token, so the API's access rules
//! are the page's.

use axum::Router;
use axum::http::{HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Redirect, Response};
use axum::routing::get;

/// The page's policy: nothing from elsewhere, nothing inline, nothing evaluated.
pub(crate) const CONTENT_SECURITY_POLICY: &str = "default-src 'none'; script-src 'self'; \
     style-src 'self'; img-src 'self'; connect-src 'self'; manifest-src 'self'; \
     base-uri 'none'; form-action 'none'; frame-ancestors 'none'; \
     require-trusted-types-for 'script'; trusted-types 'none'";

struct Asset {
    path: &'static str,
    content_type: &'static str,
    body: &'static str,
}

/// A file of `server/ui/`, compiled in.
macro_rules! asset {
    ($path:literal, $file:literal, $content_type:expr) => {
        Asset {
            path: $path,
            content_type: $content_type,
            body: include_str!(concat!("../../../ui/", $file)),
        }
    };
}

const JS: &str = "text/javascript; charset=utf-8";

const ASSETS: &[Asset] = &[
    asset!("/ui", "index.html", "text/html; charset=utf-8"),
    asset!("/ui/app.js", "app.js", JS),
    asset!("/ui/api.js", "api.js", JS),
    asset!("/ui/dom.js", "dom.js", JS),
    asset!("/ui/sections.js", "sections.js", JS),
    asset!("/ui/connection.js", "connection.js", JS),
    asset!("/ui/view.js", "view.js", JS),
    asset!("/ui/overview.js", "overview.js", JS),
    asset!("/ui/device.js", "device.js", JS),
    asset!("/ui/link.js", "link.js", JS),
    asset!("/ui/style.css", "style.css", "text/css; charset=utf-8"),
    asset!("/ui/icon.svg", "icon.svg", "image/svg+xml"),
];

fn serve(asset: &'static Asset) -> Response {
    let mut response = asset.body.into_response();
    let headers = response.headers_mut();
    headers.insert(
        header::CONTENT_TYPE,
        HeaderValue::from_static(asset.content_type),
    );
    headers.insert(
        header::CONTENT_SECURITY_POLICY,
        HeaderValue::from_static(CONTENT_SECURITY_POLICY),
    );
    headers.insert(
        header::X_CONTENT_TYPE_OPTIONS,
        HeaderValue::from_static("nosniff"),
    );
    headers.insert(
        header::REFERRER_POLICY,
        HeaderValue::from_static("no-referrer"),
    );
    headers.insert(header::X_FRAME_OPTIONS, HeaderValue::from_static("DENY"));
    // The assets change with the binary: always revalidate, never serve a stale page.
    headers.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-cache"));
    response
}

/// `/` redirects to `/ui`; `/ui` and `/ui/` are the page; `/ui/{asset}` its files.
pub(crate) fn routes<S: Clone + Send + Sync + 'static>() -> Router<S> {
    let mut router = Router::new()
        .route("/", get(|| async { Redirect::to("/ui") }))
        .route("/ui/", get(|| async { serve(&ASSETS[0]) }));
    for asset in ASSETS {
        router = router.route(asset.path, get(move || async move { serve(asset) }));
    }
    router.route(
        "/ui/{*rest}",
        get(|| async {
            (
                StatusCode::NOT_FOUND,
                [(header::CONTENT_TYPE, "text/plain; charset=utf-8")],
                "no such file of the web page",
            )
        }),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_page_loads_only_its_own_files() {
        let html = ASSETS[0].body;
        assert!(!html.contains("<script>"), "no inline script");
        assert!(!html.contains("style="), "no inline style");
        assert!(!html.contains("http://") && !html.contains("https://"));
        for asset in ASSETS {
            assert!(
                !asset.body.contains("innerHTML") && !asset.body.contains("eval("),
                "{}: no string sinks",
                asset.path
            );
        }
        // Every file the page refers to is served.
        for needed in ["/ui/app.js", "/ui/style.css", "/ui/icon.svg"] {
            assert!(html.contains(needed), "{needed}");
        }
    }
}
