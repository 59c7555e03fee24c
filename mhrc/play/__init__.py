"""`mhrc play`: a person drives one robot from a browser page beside AI teammates.

The page's server is one more agent of the world (mhrc.play.session): it attaches its robot as
any agent does and sees only that robot's observations. `HumanPolicy` (mhrc.play.human) is the
policy whose decisions the person makes; `forms` the controls and the checks of a submission;
`app` the Starlette app and uvicorn; `page` the page; `house` its map; `runner` the runs.
"""
